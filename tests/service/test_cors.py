"""CORS from a real browser: a headless Chromium page on another origin calls the API.

The page (served by a second local HTTP server) fetches ``/v1/scans`` with an ``Authorization``
header (a preflighted request) and synthesizes a body with a JSON POST, then writes what it got
into the DOM, which ``chromium --dump-dom`` prints. An origin on ``BODYSPACE_CORS_ORIGINS`` gets
answers; any other origin (and every origin by default) is refused by the browser.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import httpx
import pytest

from service.testing import free_port, service_env, start_server

KEY = "test-key-cors"

PAGE = """<!doctype html><html><body><pre id="out">pending</pre><script>
(async () => {
  const out = document.getElementById("out");
  const api = "%(api)s", auth = {"Authorization": "Bearer %(key)s"};
  try {
    const r = await fetch(api + "/v1/scans", {headers: auth});
    const j = await r.json();
    const s = await fetch(api + "/v1/models/default/synthesize", {
      method: "POST", headers: {...auth, "Content-Type": "application/json"},
      body: JSON.stringify({sex: "female", height_m: 1.65}),
    });
    out.textContent = "ok scans=" + r.status + " items=" + j.items.length +
      " synthesize=" + s.status + " " + s.headers.get("Content-Type");
  } catch (e) {
    out.textContent = "refused " + e.name;
  }
})();
</script></body></html>"""


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    pytest.fail(
        "Chromium is needed for the CORS test (.ci/run installs it: apt-get install chromium)"
    )


@pytest.fixture()
def page_server() -> Iterator[tuple[int, dict[str, str]]]:
    """A second local HTTP server (another origin) serving ``/page`` = ``pages["page"]``."""
    pages: dict[str, str] = {}

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = pages.get(self.path.strip("/"), "").encode()
            self.send_response(200 if body else 404)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    port = free_port()
    httpd = ThreadingHTTPServer(("127.0.0.1", port), Handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    try:
        yield port, pages
    finally:
        httpd.shutdown()


def _browse(url: str) -> str:
    """The DOM of ``url`` after its script ran, from a headless Chromium."""
    with tempfile.TemporaryDirectory() as profile:
        out = subprocess.run(
            [
                _chromium(), "--headless", "--no-sandbox", "--disable-gpu",
                "--disable-background-networking", "--disable-component-update",
                "--no-first-run", f"--user-data-dir={profile}",
                "--virtual-time-budget=20000", "--dump-dom", url,
            ],
            capture_output=True, text=True, timeout=90,
        )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


@pytest.mark.parametrize("allowed", [True, False])
def test_browser_page_on_another_origin(tmp_path, page_server, allowed):
    page_port, pages = page_server
    origin = f"http://127.0.0.1:{page_port}"
    # allowed: the page's origin is listed; refused: only some other origin is
    listed = origin if allowed else "https://app.example.com"
    env = service_env(
        {
            "BODYSPACE_DATA_DIR": str(tmp_path / "data"),
            "BODYSPACE_API_KEY": KEY,
            "BODYSPACE_CORS_ORIGINS": f"{listed}, http://localhost:9",
        }
    )
    port = free_port()
    api = start_server(env, port, tmp_path / "api.log")
    try:
        # the page uses "localhost" for the API: another host and port than the page's origin
        pages["page"] = PAGE % {"api": f"http://localhost:{port}", "key": KEY}
        dom = _browse(f"{origin}/page")
    finally:
        api.stop()
    if allowed:
        print(dom[dom.index("<pre") : dom.index("</pre>")])
        assert "ok scans=200 items=0 synthesize=200 model/gltf-binary" in dom, dom
    else:
        assert "refused TypeError" in dom, dom


def test_cors_closed_by_default(client):
    """The shared test server has no BODYSPACE_CORS_ORIGINS: no preflight passes, no answer
    carries Access-Control-Allow-Origin."""
    origin = {"Origin": "http://127.0.0.1:1"}
    pre = httpx.options(
        str(client.base_url) + "/v1/scans",
        headers={**origin, "Access-Control-Request-Method": "GET",
                 "Access-Control-Request-Headers": "authorization"},
    )  # fmt: skip
    assert "access-control-allow-origin" not in pre.headers
    r = client.get("/v1/scans", headers=origin)
    assert r.status_code == 200 and "access-control-allow-origin" not in r.headers
