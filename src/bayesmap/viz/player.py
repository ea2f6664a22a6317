"""The offline page that steps through a chain's frames (:func:`player_page`), the body of
:func:`bayesmap.viz.animation.chain_html`: one self-contained HTML document, the frames embedded as base64 PNG data
URIs, plain inline CSS and JavaScript, no external resource or link.

Elements: ``<img id="chain-frame">`` (the current frame), ``<input type="range" id="chain-slider">`` (frame index,
``0 .. F - 1``), ``<output id="chain-sweep">`` (the sweep number of the current frame), and ``<button
id="chain-play">`` (play / pause; playing stops on the last frame). With focus on the page, the arrow keys step and
the space bar plays and pauses.
"""

from __future__ import annotations

import base64
import html
import json
from io import BytesIO

from PIL import Image

__all__ = ["player_page", "png_data_uri"]

_TEMPLATE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
  body {{ font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 1.5em;
         color: #222; background: #fff; }}
  h1 {{ font-size: 1.3em; font-weight: 600; margin: 0 0 0.6em 0; }}
  #chain-frame {{ display: block; max-width: 100%; height: auto; border: 1px solid #ddd;
                  image-rendering: auto; }}
  .controls {{ display: flex; align-items: center; gap: 0.8em; margin-top: 0.6em; max-width: {width}px; }}
  #chain-slider {{ flex: 1; }}
  #chain-play {{ min-width: 5em; padding: 0.25em 0.8em; font-size: 1em; cursor: pointer; }}
  .sweep {{ font-variant-numeric: tabular-nums; white-space: nowrap; }}
  .hint {{ color: #777; font-size: 0.85em; margin-top: 0.4em; }}
</style>
</head>
<body>
<h1>{title}</h1>
<img id="chain-frame" width="{width}" height="{height}" alt="frame of the Gibbs chain animation">
<noscript><p>This page needs JavaScript to show the frames.</p></noscript>
<div class="controls">
  <button id="chain-play" type="button">Play</button>
  <input id="chain-slider" type="range" min="0" max="{last_index}" step="1" value="0" aria-label="frame">
  <span class="sweep">sweep <output id="chain-sweep" for="chain-slider">{first_sweep}</output> of {num_sweeps}</span>
</div>
<p class="hint">{num_frames} frames. Drag the slider or use the arrow keys; space plays and pauses.</p>
<script>
(function () {{
  "use strict";
  var frames = {frames};
  var sweeps = {sweeps};
  var delay = {delay};
  var img = document.getElementById("chain-frame");
  var slider = document.getElementById("chain-slider");
  var sweep = document.getElementById("chain-sweep");
  var button = document.getElementById("chain-play");
  var timer = null;
  function show(k) {{
    k = Math.max(0, Math.min(frames.length - 1, k));
    slider.value = String(k);
    img.src = frames[k];
    sweep.textContent = String(sweeps[k]);
  }}
  function pause() {{
    if (timer !== null) {{ clearInterval(timer); timer = null; }}
    button.textContent = "Play";
  }}
  function play() {{
    if (frames.length < 2) {{ return; }}
    if (Number(slider.value) >= frames.length - 1) {{ show(0); }}
    button.textContent = "Pause";
    timer = setInterval(function () {{
      var k = Number(slider.value) + 1;
      show(k);
      if (k >= frames.length - 1) {{ pause(); }}
    }}, delay);
  }}
  button.addEventListener("click", function () {{ if (timer === null) {{ play(); }} else {{ pause(); }} }});
  slider.addEventListener("input", function () {{ pause(); show(Number(slider.value)); }});
  document.addEventListener("keydown", function (event) {{
    if (event.target === slider || event.target === button) {{ return; }}
    if (event.key === "ArrowRight") {{ pause(); show(Number(slider.value) + 1); event.preventDefault(); }}
    else if (event.key === "ArrowLeft") {{ pause(); show(Number(slider.value) - 1); event.preventDefault(); }}
    else if (event.key === " ") {{ if (timer === null) {{ play(); }} else {{ pause(); }} event.preventDefault(); }}
  }});
  show(0);
}})();
</script>
</body>
</html>
"""


def png_data_uri(frame: Image.Image) -> str:
    """A frame (RGB or palette :class:`PIL.Image.Image`) as a PNG data URI (``data:image/png;base64,...``)."""
    buffer = BytesIO()
    frame.save(buffer, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def player_page(frames: list[Image.Image], sweeps, total: int, title: str, delay: int) -> str:
    """The HTML document that steps through ``frames``.

    Args:
        frames: ``F >= 1`` images of one size (RGB or palette), each embedded once as a PNG data URI.
        sweeps: ``(F,)`` ints, the sweep number each frame shows.
        total: the chain's number of sweeps ``T`` (shown as "sweep t of T").
        title: the page title and heading, plain text (HTML-escaped here).
        delay: milliseconds per frame while playing.

    Returns:
        The document as a str.
    """
    width, height = frames[0].size
    uris = [png_data_uri(frame) for frame in frames]
    return _TEMPLATE.format(
        title=html.escape(title, quote=True),
        width=width,
        height=height,
        last_index=len(frames) - 1,
        first_sweep=int(sweeps[0]),
        num_sweeps=total,
        num_frames=len(frames),
        frames="[\n" + ",\n".join(json.dumps(uri) for uri in uris) + "\n]",
        sweeps=json.dumps([int(s) for s in sweeps]),
        delay=delay,
    )
