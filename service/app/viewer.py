"""The browser viewer at `/`, Swagger UI at `/docs` and ReDoc at `/redoc`, all served from
installed files, so all three work offline.

The viewer is plain HTML/JS/CSS in `static/` (no build step, nothing from a CDN); it
talks to the public API with the key the user types once (kept in sessionStorage). The
page itself carries no data, so it is served without authentication even when the API
needs a key. Swagger UI (5.x, which reads the OpenAPI 3.1 FastAPI writes) and ReDoc come
from the `fastapi-offline` wheel's static folder; when it is missing, both pages stay
FastAPI's CDN ones. ReDoc's bundle names one remote file, its footer's Redocly logo on
cdn.redoc.ly: the bundle is served with that URL pointed at the viewer's favicon, and
both pages carry a Content-Security-Policy allowing this origin only.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.routing import Route

STATIC = Path(__file__).parent / "static"


def install(app: FastAPI) -> None:
    """Serve the viewer at `/`, its files at `/static/`, the docs pages' at
    `/docs-assets/`."""

    @app.get("/", include_in_schema=False)
    def viewer() -> FileResponse:
        return FileResponse(STATIC / "index.html", media_type="text/html",
                            headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC), name="viewer-static")
    _offline_docs(app)


DOCS_ASSETS = "/docs-assets"
REDOC_JS = "/docs-redoc.js"  # outside the mount: a route under it would never be reached
REDOC_LOGO = b"https://cdn.redoc.ly/redoc/logo-mini.svg"
# 'unsafe-inline': both pages start their bundle with an inline script; blob: and data:
# for ReDoc's web worker and its inline images.
DOCS_CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline' blob:; "
            "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; worker-src blob:")


def _replace_route(app: FastAPI, path: str) -> None:
    """Drop FastAPI's own page at `path` (its CDN-backed version) before adding ours."""
    app.router.routes[:] = [r for r in app.router.routes
                            if not (isinstance(r, Route) and r.path == path)]


def _offline_docs(app: FastAPI) -> None:
    if not app.openapi_url or not (app.docs_url or app.redoc_url):
        return  # docs are off (an API key is set)
    try:
        import fastapi_offline
    except ImportError:
        return
    assets = Path(fastapi_offline.__file__).parent / "static"
    app.mount(DOCS_ASSETS, StaticFiles(directory=assets), name="docs-assets")
    openapi_url, title = app.openapi_url, app.title
    if app.docs_url:
        _replace_route(app, app.docs_url)
        oauth2_redirect_url = app.swagger_ui_oauth2_redirect_url

        @app.get(app.docs_url, include_in_schema=False)
        def swagger_ui() -> HTMLResponse:
            return _offline(get_swagger_ui_html(
                openapi_url=openapi_url, title=f"{title} - Swagger UI",
                swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
                swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
                swagger_favicon_url="/static/favicon.svg",
                oauth2_redirect_url=oauth2_redirect_url))
    if app.redoc_url:
        _replace_route(app, app.redoc_url)
        bundle = assets / "redoc.standalone.js"

        @app.get(REDOC_JS, include_in_schema=False)
        def redoc_js() -> Response:
            return Response(_local_redoc(bundle), media_type="text/javascript",
                            headers={"Cache-Control": "public, max-age=86400"})

        @app.get(app.redoc_url, include_in_schema=False)
        def redoc() -> HTMLResponse:
            return _offline(get_redoc_html(
                openapi_url=openapi_url, title=f"{title} - ReDoc",
                redoc_js_url=REDOC_JS,
                redoc_favicon_url="/static/favicon.svg", with_google_fonts=False))


@cache
def _local_redoc(bundle: Path) -> bytes:
    """ReDoc's bundle with its one remote URL (the footer logo) made local."""
    return bundle.read_bytes().replace(REDOC_LOGO, b"/static/favicon.svg")


def _offline(page: HTMLResponse) -> HTMLResponse:
    page.headers["Content-Security-Policy"] = DOCS_CSP
    return page
