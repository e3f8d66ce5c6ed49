"""The skin, live in a browser: ``eskin listen PORT --web [HOST:]PORT``.

:class:`LiveState` observes the listener's events in the listener's thread (appending
references to bounded deques, never waiting) and turns them, in the server's thread, into what
the page shows: a heat map of per-taxel energy, decimated traces, the touch windows and every
decision, the link statistics and, with a replay file, the accuracy against its true classes.
:class:`WebServer` serves the page (``static/``: hand-written HTML, script and style, shipped
with the package) and a WebSocket over aiohttp, on its own event loop in its own thread.
See docs/live-page.md.
"""

from ._server import WebServer, parse_web_address, render_page
from ._state import LiveState

__all__ = ["LiveState", "WebServer", "parse_web_address", "render_page"]
