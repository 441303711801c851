"""`leadthrough view --http-port`: the live view as a page any browser on the cell PC opens.

The standard library's HTTP server, on a thread of its own, serves the two files shipped beside
this module, ``index.html`` and ``live_view.js`` (no CDN, no build step: the cell PC is
offline). The page connects to the view's Foxglove WebSocket server itself, on the port this
server writes into it, and draws the joint positions, the arm and the lifecycle state. Only
these files, only GET; one request at a time (HTTP/1.0, the connection closes after each).
"""

from __future__ import annotations

import logging
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, HTTPServer
from pathlib import Path
from typing import Any

log = logging.getLogger("leadthrough.view")

PAGE_DIR = Path(__file__).parent
#: URL path → (file beside this module, content type)
PAGE_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/live_view.js": ("live_view.js", "text/javascript; charset=utf-8"),
}
#: replaced in every served file by the Foxglove WebSocket server's port
WS_PORT_PLACEHOLDER = b"{{WS_PORT}}"
#: a client that sends its request slower than this is dropped [s]
REQUEST_TIMEOUT_S = 5.0
#: how soon :meth:`PageServer.stop` is noticed by the serving thread [s]
SHUTDOWN_POLL_S = 0.1


class PageServer:
    """Serve the page on ``host:port`` (port 0: any free port; :attr:`port` tells which) for
    the Foxglove WebSocket server on ``ws_port``."""

    def __init__(self, host: str, port: int, ws_port: int) -> None:
        self.host, self.requested_port = host, port
        files = {name for name, _ in PAGE_FILES.values()}
        # Read at start, so that a broken install is refused before anyone opens the page.
        contents = {
            name: (PAGE_DIR / name).read_bytes().replace(WS_PORT_PLACEHOLDER, str(ws_port).encode())
            for name in files
        }
        self._pages = {path: (contents[name], ctype) for path, (name, ctype) in PAGE_FILES.items()}
        self._httpd: HTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return int(self._httpd.server_address[1]) if self._httpd is not None else 0

    def start(self) -> None:
        pages = self._pages

        class Handler(BaseHTTPRequestHandler):
            timeout = REQUEST_TIMEOUT_S

            def do_GET(self) -> None:
                page = pages.get(self.path.split("?", 1)[0])
                if page is None:
                    self.send_error(HTTPStatus.NOT_FOUND)
                    return
                body, ctype = page
                self.send_response(HTTPStatus.OK)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: Any) -> None:
                log.debug("http %s: " + format, self.address_string(), *args)

        self._httpd = HTTPServer((self.host, self.requested_port), Handler)
        self._thread = threading.Thread(
            target=self._httpd.serve_forever,
            kwargs={"poll_interval": SHUTDOWN_POLL_S},
            name="live-view-http",
            daemon=True,
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop serving and close the socket (idempotent)."""
        if self._httpd is None:
            return
        if self._thread is not None:
            self._httpd.shutdown()
            self._thread.join()
            self._thread = None
        self._httpd.server_close()
        self._httpd = None
