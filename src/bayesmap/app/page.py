"""The explorer's NiceGUI page: one :class:`ExplorerPage` per browser tab, built panel by panel and wired to its
:class:`~bayesmap.app.explorer.Explorer` (:func:`build_page`), and the server (:func:`run_app`).

NiceGUI is imported inside the functions that need it (it takes a second to import): importing this module does
not import it.
"""

from __future__ import annotations

import numpy as np

from bayesmap.app.explorer import SETTINGS, Explorer
from bayesmap.app.svg import legend_gradient
from bayesmap.errors import BayesmapError


class ExplorerPage:
    """The NiceGUI page of one :class:`Explorer`: the header, the map panel, the controls panel, and the handlers
    that connect them to the explorer. Build it inside a NiceGUI page function (it creates its elements in the
    current client); :func:`build_page` does.

    Args:
        explorer: the session's state; default a new :class:`Explorer` of the tutorial's scene.

    Attributes:
        ex: the explorer.
        image: the drawing (an ``interactive_image`` whose content is :meth:`Explorer.svg`).
    """

    def __init__(self, explorer: Explorer | None = None):
        from nicegui import ui

        self.ui = ui
        self.ex = explorer or Explorer()
        self.drag = {"mode": None, "paint": None, "last": None}
        self._build_header()
        with ui.row().classes("items-start no-wrap gap-6"):
            self._build_map_panel()
            with ui.column().classes("gap-1").style("min-width: 360px"):
                self._build_settings()
                self._build_run_controls()
                self._build_path_controls()
                self._build_view_controls()
                self._build_file_controls()
        self._connect()
        self.redraw()

    # -- the elements, top to bottom and left to right ---------------------------------------------------------

    def _build_header(self) -> None:
        """Title, instructions and the line where errors are shown."""
        ui = self.ui
        ui.page_title("bayesmap explorer")
        ui.label("bayesmap: Bayesian occupancy-grid mapping").classes("text-h5")
        ui.label("Click a cell to toggle a wall, drag to paint, drag the orange sensor to move it. Run inference "
                 "to infer the walls from the beams' noisy range readings. In path mode, clicks on free cells add "
                 "poses to a path and Run SLAM infers the path and the map from simulated odometry and readings "
                 "(green: posterior mean path, dots: pose samples, grey dashes: odometry).").classes(
            "text-body2 text-grey-8")
        self.message = ui.label("").classes("bm-message text-negative text-body1")

    def _build_map_panel(self) -> None:
        """The drawing, the colour scale of the inferred walls and the status line."""
        ui = self.ui
        width, height = self.ex.image_size()
        with ui.column().style(f"width: {width}px") as self.left:
            self.image = ui.interactive_image(size=(width, height), content="", cross=False, sanitize=False,
                                              events=["mousedown", "mousemove", "mouseup", "mouseleave"])
            self.image.classes("bm-map").style(f"width: {width}px; height: {height}px; cursor: crosshair")
            with ui.row().classes("items-center no-wrap gap-2"):
                ui.label("inferred wall probability: 0").classes("text-caption")
                self.legend = (ui.element("div").classes("bm-legend")
                               .style("width: 160px; height: 12px; border: 1px solid #999"))
                ui.label("1").classes("text-caption")
            self.status = ui.label("").classes("bm-status text-body2")

    def _build_settings(self) -> None:
        """One slider and one text field per setting of :data:`SETTINGS`."""
        ui = self.ui
        self.fields = {}
        for name, setting in SETTINGS.items():
            with ui.row().classes("items-center no-wrap w-full"):
                ui.label(setting.label).classes("w-40")
                slider = ui.slider(min=setting.low, max=setting.high, step=setting.step,
                                   value=getattr(self.ex, name)).classes(f"bm-slider-{name} w-40")
                number = ui.input(value=str(getattr(self.ex, name))).classes(f"bm-field-{name} w-20").props("dense")
            self.fields[name] = (slider, number)

    def _build_run_controls(self) -> None:
        """Run inference, Clear walls, Clear inferred walls, and the progress bar of a run."""
        ui, ex = self.ui, self.ex
        with ui.row():
            self.run_button = ui.button("Run inference").classes("bm-run")
            (ui.button("Clear walls", on_click=lambda: (ex.clear_walls(), self.redraw()))
             .classes("bm-clear-walls").props("outline"))
            (ui.button("Clear inferred walls", on_click=lambda: (ex.clear_inferred(), self.redraw()))
             .classes("bm-clear-inferred").props("outline"))
        self.progress = ui.linear_progress(value=0.0, show_value=False).classes("bm-progress")
        self.progress.set_visibility(False)

    def _build_path_controls(self) -> None:
        """The path mode switch, Clear path, and the line with the last SLAM run's ATEs."""
        ui = self.ui
        ui.separator()
        with ui.row().classes("items-center"):
            self.path_switch = ui.switch("path mode (clicks add poses; Run SLAM)", value=False).classes("bm-path-mode")
            self.clear_path_button = (ui.button("Clear path", on_click=lambda: (self.ex.clear_path(), self.redraw()))
                                      .classes("bm-clear-path").props("outline"))
        self.slam_label = ui.label("").classes("bm-slam text-body2")

    def _build_view_controls(self) -> None:
        """What to show after a run: the average or one sample, as opacity or heatmap."""
        ui = self.ui
        ui.separator()
        self.average = ui.switch("show average", value=True).classes("bm-average")
        with ui.row().classes("items-center no-wrap w-full"):
            ui.label("sample").classes("w-16")
            self.sample_slider = ui.slider(min=1, max=2, step=1, value=1).classes("bm-sample w-56").props("label")
            self.sample_label = ui.label("").classes("bm-sample-label")
        self.heat = ui.toggle(["opacity", "heatmap"], value="opacity").classes("bm-style")

    def _build_file_controls(self) -> None:
        """Load an ASCII map file, save the drawn map."""
        ui, ex = self.ui, self.ex
        ui.separator()
        ui.label("Map file (ASCII: 'X' wall, '.' free; line i, column j is cell (i, j))").classes("text-caption")
        with ui.row().classes("items-center"):
            self.upload = (ui.upload(label="Load map", auto_upload=True, max_files=1)
                           .classes("bm-upload").props("accept=.txt,text/plain flat bordered"))
            (ui.button("Save map", on_click=lambda: ui.download.content(ex.map_text().encode(), "map.txt"))
             .classes("bm-save").props("outline"))

    def _connect(self) -> None:
        """Wire the elements' events to the handlers below."""
        self.image.on_mouse(self.on_mouse)
        for name, (slider, number) in self.fields.items():
            slider.on_value_change(lambda e, n=name, s=slider: self.apply_setting(n, e.value, s))
            number.on("keydown.enter", lambda _e, n=name, f=number: self.apply_setting(n, f.value, f))
            number.on("blur", lambda _e, n=name, f=number: self.apply_setting(n, f.value, f))
        self.run_button.on_click(self.run_clicked)
        self.path_switch.on_value_change(lambda e: (self.ex.set_path_mode(e.value), self.clear_error(), self.redraw()))
        self.average.on_value_change(lambda _e: self.redraw())
        self.sample_slider.on_value_change(lambda _e: self.redraw())
        self.heat.on_value_change(lambda _e: self.redraw())
        self.upload.on_upload(self.on_upload)

    # -- handlers ------------------------------------------------------------------------------------------------

    def show_error(self, text: str) -> None:
        """Show ``text`` on the error line and as a notification."""
        self.message.set_text(text)
        self.ui.notify(text, type="negative")

    def clear_error(self) -> None:
        """Empty the error line."""
        self.message.set_text("")

    def redraw(self) -> None:
        """Redraw the map, the colour scale, the sample controls and the status line from the explorer's state."""
        ex = self.ex
        result_on = ex.result is not None
        shown = ex.shown(None if (self.average.value or not result_on) else int(self.sample_slider.value) - 1)
        self.image.content = ex.svg(shown, heatmap=self.heat.value == "heatmap")
        self.legend.style(f"background: {legend_gradient(self.heat.value == 'heatmap')}")
        self.run_button.set_text("Run SLAM" if ex.path_mode else "Run inference")
        self.clear_path_button.set_visibility(ex.path_mode)
        self.slam_label.set_visibility(ex.path_mode)
        self.slam_label.set_text(ex.slam_text())
        self.sample_slider.set_enabled(result_on and not self.average.value and not ex.path_mode)
        if ex.path_mode:
            self.sample_label.set_text("path mode: the SLAM posterior's average")
        elif result_on:
            n = len(ex.result.samples)
            self.sample_slider.props(f"max={n}")
            self.sample_label.set_text("average of sweeps %d-%d" % (ex.result.summary["burn_in"] + 1, n)
                                       if self.average.value else f"sweep {int(self.sample_slider.value)} of {n}")
        else:
            self.sample_label.set_text("no inference yet")
        self.status.set_text(ex.status())

    def on_mouse(self, e) -> None:
        """Mouse down on the sensor starts moving it, elsewhere toggles the cell and starts painting; moves with the
        button held move the sensor or paint; button up or leaving the drawing ends the drag."""
        ex, drag = self.ex, self.drag
        xy = ex.to_world(e.image_x, e.image_y)
        if ex.path_mode:
            if e.type == "mousedown":
                self.add_pose(xy)
            return
        if e.type == "mousedown":
            self.clear_error()
            if np.hypot(*(xy - ex.pos)) <= 0.6 * ex.grid.resolution:
                drag["mode"] = "sensor"
                return
            cell = ex.cell_at(xy)
            if cell is None:
                return
            new = ex.toggle(cell)
            drag["mode"] = "paint" if new is not None else None
            drag["paint"], drag["last"] = new, cell
            self.redraw()
        elif e.type == "mousemove" and drag["mode"] and (e.buttons & 1):
            if drag["mode"] == "sensor":
                if ex.move_sensor(xy):
                    self.redraw()
            else:
                cell = ex.cell_at(xy)
                if cell is not None and cell != drag["last"]:
                    drag["last"] = cell
                    ex.set_wall(cell, drag["paint"])
                    self.redraw()
        elif e.type in ("mouseup", "mouseleave") or not (e.buttons & 1):
            drag["mode"] = None

    def add_pose(self, xy) -> None:
        """Path mode: append the clicked cell to the path; a wall cell shows a message and changes nothing."""
        cell = self.ex.cell_at(xy)
        if cell is None:
            return
        try:
            self.ex.add_pose(cell)
        except BayesmapError as err:
            self.show_error(str(err))
            return
        self.clear_error()
        self.redraw()

    def apply_setting(self, name: str, value, source) -> None:
        """Set ``name`` from its slider or text field (``source``) and sync the other one; a bad value is shown
        as an error and the field is reset."""
        slider, number = self.fields[name]
        try:
            value = self.ex.set_setting(name, value)
        except BayesmapError as err:
            self.show_error(str(err))
            number.value = str(getattr(self.ex, name))
            return
        self.clear_error()
        if source is not slider and slider.value != value:
            slider.value = value
        if source is not number:
            number.value = str(value)
        self.redraw()

    async def run_clicked(self) -> None:
        """Run inference (in path mode: SLAM) in a worker thread with a progress bar (a click while a run is going
        only warns). The bar shows the fraction the run reports (:attr:`Explorer.progress`); before the run has
        reported any work done (compiling, or a stage that reports no steps) it moves without a fraction."""
        from nicegui import run

        ui, ex = self.ui, self.ex
        slam = ex.path_mode
        if slam and len(ex.path) < 2:
            self.show_error(f"the path needs at least 2 poses, it has {len(ex.path)}: click free cells to add poses")
            return
        if not ex.start_run():
            ui.notify("inference is already running", type="warning")
            return
        self.clear_error()
        self.run_button.disable()
        self.path_switch.disable()
        self.progress.set_visibility(True)
        self.progress.value = 0.0
        poll = ui.timer(0.1, self.show_progress)
        try:
            await run.io_bound(ex.run_slam if slam else ex.run)
        except BayesmapError as err:
            self.show_error(str(err))
        finally:
            poll.cancel()
            self.run_button.enable()
            self.path_switch.enable()
            self.progress.props(remove="indeterminate")
            self.progress.set_visibility(False)
            if ex.result is not None:
                self.sample_slider.value = len(ex.result.samples)
            self.redraw()

    def show_progress(self) -> None:
        """Draw the running run's progress: the bar (without a fraction until one is known) and the status line."""
        ex = self.ex
        if ex.progress_known:
            self.progress.props(remove="indeterminate")
            self.progress.set_value(ex.progress)
        else:
            self.progress.props("indeterminate")
        self.status.set_text(ex.status())

    async def on_upload(self, e) -> None:
        """Load an uploaded ASCII map and resize the drawing to it (errors shown, the map unchanged)."""
        ex = self.ex
        name = e.file.name or "uploaded file"
        try:
            data = await e.file.read()
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                raise BayesmapError(f"{name}: not a text file (expected an ASCII map of 'X' and '.')") from None
            ex.load_map_text(text, source=name)
        except BayesmapError as err:
            self.show_error(str(err))
        else:
            self.clear_error()
            width, height = ex.image_size()
            self.image._props["size"] = (width, height)
            self.image.update()
            self.image.style(f"width: {width}px; height: {height}px")
            self.left.style(f"width: {width}px")
            self.redraw()
            self.ui.notify(f"loaded {name}: {ex.grid.shape[0]} x {ex.grid.shape[1]} cells")
        finally:
            self.upload.reset()


def build_page(explorer: Explorer | None = None) -> Explorer:
    """Build the explorer's page (an :class:`ExplorerPage`) for the current NiceGUI client (one :class:`Explorer`
    per browser tab).

    Returns the page's explorer."""
    return ExplorerPage(explorer).ex


def run_app(host: str = "127.0.0.1", port: int = 8080, show: bool = True) -> None:
    """Serve the explorer at ``http://host:port/`` until interrupted (blocking).

    Args:
        host: interface to listen on (default only this machine).
        port: TCP port.
        show: open the page in the default browser.

    Raises:
        BayesmapError: if the port cannot be used (in use, or not in 1..65535).
    """
    import socket

    if not (1 <= int(port) <= 65535):
        raise BayesmapError(f"port must be between 1 and 65535, got {port!r}")
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, int(port)))
        except OSError as err:
            raise BayesmapError(f"cannot listen on {host}:{port}: {err.strerror}") from None
    from nicegui import ui

    ui.run(build_page, host=host, port=int(port), show=show, reload=False, title="bayesmap explorer",
           show_welcome_message=True, uvicorn_logging_level="warning")
