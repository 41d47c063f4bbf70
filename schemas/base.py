"""Strict pydantic base types shared by every wire-contract class.

Strictness is part of the contract: unknown fields, NaN/±Inf, booleans where numbers go
and silent string-to-number coercions are all validation errors, so a typo in a scenario
never runs a different experiment than the one the user wrote.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, Strict, StrictInt

# A float field accepts JSON integers too (users write `"L": 10`), never booleans or strings.
# (Strict mode accepts an int for a float field and still refuses bool and str.)
Real = Annotated[float, Field(allow_inf_nan=False, ge=-1e300, le=1e300), Strict(True)]
PositiveReal = Annotated[float, Field(gt=0, le=1e300, allow_inf_nan=False), Strict(True)]
NonNegativeReal = Annotated[float, Field(ge=0, le=1e300, allow_inf_nan=False), Strict(True)]
PositiveInt = Annotated[StrictInt, Field(gt=0)]
NonNegativeInt = Annotated[StrictInt, Field(ge=0)]
# Pairs accept a JSON array or a Python list or tuple (the items stay strict).
Vec2 = Annotated[tuple[Real, Real], Strict(False), Field(description="A point (x, y).")]
# A point of the plane or of space: (x, y) or (x, y, z); the scenario checks that its
# length matches `space.dimension`.
Vec3 = Annotated[tuple[Real, Real, Real], Strict(False),
                 Field(description="A point (x, y, z).")]
Point = Vec2 | Vec3
RealPair = Annotated[tuple[Real, Real], Strict(False)]
NonNegativePair = Annotated[tuple[NonNegativeReal, NonNegativeReal], Strict(False)]

# Magnitude guard: a coordinate beyond this cannot be represented with useful precision
# next to the unit-scale distances the models use.
MAX_ABS_COORD = 1e12


class Strict(BaseModel):
    """Base of every schema class: forbid extra fields, no coercion, immutable."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, validate_default=True)
