"""The browser viewer at `/` and Swagger UI served from the package, so both work offline.

The viewer is plain HTML/JS/CSS in `static/` (no build step, nothing from a CDN); it
talks to the public API with the key the user types once (kept in sessionStorage). The
page itself carries no data, so it is served without authentication even when the API
needs a key. Swagger UI's files come from the `swagger-ui-bundle` wheel; when it is
missing, `/docs` stays FastAPI's CDN page.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles
from starlette.routing import Route

STATIC = Path(__file__).parent / "static"


def install(app: FastAPI) -> None:
    """Serve the viewer at `/`, its files at `/static/`, Swagger UI's at `/swagger-ui/`."""

    @app.get("/", include_in_schema=False)
    def viewer() -> FileResponse:
        return FileResponse(STATIC / "index.html", media_type="text/html",
                            headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC), name="viewer-static")
    _offline_docs(app)


def _offline_docs(app: FastAPI) -> None:
    if not app.docs_url or not app.openapi_url:
        return  # docs are off (an API key is set)
    try:
        from swagger_ui_bundle import swagger_ui_path
    except ImportError:
        return
    app.mount("/swagger-ui", StaticFiles(directory=swagger_ui_path), name="swagger-ui")
    docs_url, openapi_url = app.docs_url, app.openapi_url
    # Replace FastAPI's CDN-backed page by the same page pointing at the local files.
    app.router.routes[:] = [r for r in app.router.routes
                            if not (isinstance(r, Route) and r.path == docs_url)]

    @app.get(docs_url, include_in_schema=False)
    def swagger_ui() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url=openapi_url, title=f"{app.title} - Swagger UI",
                                   swagger_js_url="/swagger-ui/swagger-ui-bundle.js",
                                   swagger_css_url="/swagger-ui/swagger-ui.css",
                                   swagger_favicon_url="/static/favicon.svg",
                                   oauth2_redirect_url=app.swagger_ui_oauth2_redirect_url)
