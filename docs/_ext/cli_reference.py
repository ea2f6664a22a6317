"""MkDocs hook: the command-line reference (docs/cli.md), generated from the typer app when the site is built.

docs/cli.md holds one marker line, ``<!-- bayesmap-cli-reference -->``; this hook replaces it with the Markdown that
typer's own documentation generator writes for the app (``typer.cli.get_docs_for_click``, what ``typer bayesmap.cli
utils docs`` prints), one level below the page's title, before the page is converted. So the reference is the
command line's own help (every command, argument and option with its default) and cannot drift from
``bayesmap COMMAND --help``.

Why not a plugin: typer 0.29 builds its commands from its own copy of click (``typer._click``), which
``mkdocs-click`` 0.9.0 does not recognize (its pages list the commands without a single option), and
``mkdocs-typer2`` 0.4.1 either reads click's attributes that typer's options lack (its "native" engine fails) or runs
the same generator as a subprocess found on ``PATH`` and renders its output with a bare Markdown converter, which
drops every ``<path>``-style metavar, turns the usage blocks into inline code, and renders nothing, without a
warning, when the subprocess fails.

A page without the marker, or a reference that lacks a command of the app, fails the build.
"""

from __future__ import annotations

import re
import warnings

from mkdocs.exceptions import PluginError

CLI_PAGE = "cli.md"
MARKER = "<!-- bayesmap-cli-reference -->"
PROGRAM = "bayesmap"


def _command():
    try:
        with warnings.catch_warnings():  # JAX's and its dependencies' deprecation notices are not the site's
            warnings.simplefilter("ignore", DeprecationWarning)
            from bayesmap import cli
    except Exception as error:  # report what broke the import in one line, not a traceback
        raise PluginError(f"{CLI_PAGE}: cannot import bayesmap.cli for the CLI reference: {error!r}") from error
    return cli.click_command


def reference_markdown() -> str:
    """The reference of every command, as typer's generator writes it, its headings one level down (``##`` for the
    program, ``###`` for each command), so that the page's own title stays the only top-level heading."""
    import typer
    from typer.cli import get_docs_for_click

    command = _command()
    text = get_docs_for_click(obj=command, ctx=typer.Context(command, info_name=PROGRAM), name=PROGRAM)
    text = re.sub(r"^(#+) ", r"#\1 ", text, flags=re.M)
    missing = [name for name in sorted(command.commands) if f"`{PROGRAM} {name}`" not in text]
    if missing:
        raise PluginError(f"{CLI_PAGE}: the generated CLI reference lacks the command(s) {', '.join(missing)}")
    return text.strip() + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri != CLI_PAGE:
        return markdown
    if MARKER not in markdown:
        raise PluginError(f"{CLI_PAGE}: the marker {MARKER!r} is missing, so the CLI reference would be empty")
    return markdown.replace(MARKER, reference_markdown())
