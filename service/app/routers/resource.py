"""The routes every kind of job has, made once for each kind: submit, list, get (with
long-poll), cancel and follow as Server-Sent Events.

/v1/jobs and /v1/sweeps are one resource inside (one row of the job store, `kind` apart):
`add_routes` registers the five routes of a `Resource` on its router with the same
endpoints (`submit.accept` and `follow`) and the same words, while each kind keeps its
public face: its path parameter (`job_id`, `sweep_id`), its view, its endpoint names
(which make the OpenAPI operation ids) and the words that are its own. The endpoints'
signatures are built from those names (FastAPI reads `__signature__`), so each kind's
OpenAPI document stays what it was when the two were written apart.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import APIRouter, Header, Query, Request
from fastapi.responses import JSONResponse, StreamingResponse
from pydantic import BaseModel

from ..deps import HubDep, RuntimeDep, SettingsDep
from ..follow import Until, cancel_row, event_stream, list_page, long_poll
from ..submit import accept


@dataclass(frozen=True)
class Resource:
    """A kind of job as its routes show it: what differs between /v1/jobs and
    /v1/sweeps (the rest of their words is written once, in `add_routes`, with the
    kind's name in it)."""

    kind: str  # the store's kind, and its name in the routes' words: "job", "sweep"
    id_name: str  # the path parameter: "job_id", "sweep_id"
    id_type: Any  # its annotated type (a UUID, described)
    state_type: Any  # what the list's `status` filter takes
    view: type[BaseModel]  # a row's view
    page: type[BaseModel]  # a page of the list
    get_name: str  # the get endpoint's name (it makes the OpenAPI operation id)
    submit_summary: str
    submit_description: str
    body_schemas: tuple[str, ...]  # what the body may be (it is parsed by hand: `submit`)
    body_examples: dict[str, Any]
    get_description: str
    cancel_description: str
    events_description: str
    list_filters: list[inspect.Parameter] = field(default_factory=list)  # after `status`


def add_routes(router: APIRouter, res: Resource) -> None:
    """Register the five routes of `res` on `router`."""
    kind, id_name = res.kind, res.id_name

    async def submit(request: Request, runtime: Any, settings: Any,
                     idempotency_key: str | None) -> JSONResponse:
        return await accept(kind, request, runtime, settings, idempotency_key)

    def list_rows(runtime: Any, settings: Any, status: Any, limit: int, cursor: str | None,
                  **filters: Any) -> Any:
        items, next_cursor = list_page(kind, runtime, settings, status or (), limit, cursor,
                                       **filters)
        return res.page(items=items, next_cursor=next_cursor)

    async def get(runtime: Any, settings: Any, hub: Any, wait: float, until: Until,
                  **ids: Any) -> Any:
        return await long_poll(kind, ids[id_name], runtime, settings, hub, wait, until)

    def cancel(runtime: Any, settings: Any, **ids: Any) -> Any:
        return cancel_row(kind, ids[id_name], runtime, settings)

    async def events(runtime: Any, settings: Any, hub: Any, **ids: Any) -> StreamingResponse:
        return await event_stream(kind, ids[id_name], runtime, settings, hub)

    row_id = _param(id_name, res.id_type)
    runtime, settings, hub = (_param("runtime", RuntimeDep), _param("settings", SettingsDep),
                              _param("hub", HubDep))
    key = _param("idempotency_key", Annotated[str | None, Header(
        alias="Idempotency-Key", min_length=1, max_length=200, pattern=r"^[\x21-\x7e]+$",
        description=f"Any unique string; retries with the same key return the same {kind}.",
    )], None)
    status = _param("status", Annotated[list[res.state_type] | None, Query(
        description="Only these statuses.")], None)
    limit = _param("limit", Annotated[int, Query(ge=1, le=500)], 50)
    cursor = _param("cursor", Annotated[str | None, Query(
        max_length=64, description="From `next_cursor`.")], None)
    wait = _param("wait", Annotated[float, Query(ge=0, le=60, description=(
        f"Long-poll: answer as soon as the {kind} is finished (or, with until=change, as "
        "soon as it changes), or after this many seconds."))], 0)
    until = _param("until", Annotated[Until, Query(description=(
        f"What a long-poll waits for: the {kind}'s end (default) or its next change."))],
        "finished")
    following = {401: {}, 404: {}, 422: {}}
    router.add_api_route(
        "", _named(submit, "submit", [_param("request", Request), runtime, settings, key]),
        methods=["POST"], status_code=202, response_model=res.view,
        summary=res.submit_summary, description=res.submit_description,
        responses={400: {}, 401: {}, 409: {}, 413: {}, 422: {}, 429: {}, 503: {}},
        openapi_extra={"requestBody": {"required": True, "content": {"application/json": {
            "schema": {"oneOf": [{"$ref": f"#/components/schemas/{name}"}
                                 for name in res.body_schemas]},
            "examples": res.body_examples}}}})
    router.add_api_route(
        "", _named(list_rows, f"list_{kind}s",
                   [runtime, settings, status, *res.list_filters, limit, cursor]),
        methods=["GET"], response_model=res.page, summary=f"List {kind}s, newest first",
        responses={401: {}, 422: {}})
    router.add_api_route(
        f"/{{{id_name}}}", _named(get, res.get_name,
                                  [row_id, runtime, settings, hub, wait, until]),
        methods=["GET"], response_model=res.view, summary=f"Get a {kind}",
        description=res.get_description, responses=following)
    router.add_api_route(
        f"/{{{id_name}}}/cancel", _named(cancel, "cancel", [row_id, runtime, settings]),
        methods=["POST"], status_code=202, response_model=res.view,
        summary=f"Cancel a {kind}", description=res.cancel_description,
        responses={**following, 409: {}})
    router.add_api_route(
        f"/{{{id_name}}}/events", _named(events, "events", [row_id, runtime, settings, hub]),
        methods=["GET"], summary=f"Follow a {kind} as Server-Sent Events",
        response_class=StreamingResponse,
        responses={200: {"content": {"text/event-stream": {"schema": {"type": "string"}},
                                     "application/json": None},
                         "description": res.events_description}, **following})


def _param(name: str, annotation: Any, default: Any = inspect.Parameter.empty
           ) -> inspect.Parameter:
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, annotation=annotation,
                             default=default)


def _named(call: Callable[..., Any], name: str, params: list[inspect.Parameter]
           ) -> Callable[..., Any]:
    """`call` as the endpoint `name` taking `params` (by keyword): what FastAPI reads."""
    if inspect.iscoroutinefunction(call):
        async def endpoint(**kwargs: Any) -> Any:
            return await call(**kwargs)
    else:
        def endpoint(**kwargs: Any) -> Any:
            return call(**kwargs)
    endpoint.__name__ = endpoint.__qualname__ = name
    endpoint.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    return endpoint
