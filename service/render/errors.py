"""The render package's user-facing errors (importable without h5py or matplotlib)."""

from __future__ import annotations


class RenderInputError(ValueError):
    """The folder, frame or option cannot be drawn: a message for the user.

    `loc` names the option at fault (the HTTP routes report it as `query.<loc>`);
    `status` is the HTTP status it stands for (422 bad option, 404 nothing to draw).
    """

    def __init__(self, message: str, *, loc: str | None = None, status: int = 422):
        super().__init__(message)
        self.loc = loc
        self.status = status


class PlottingUnavailable(RuntimeError):
    """matplotlib (the `flocklab[plot]` extra) is not installed."""
