"""Every model family's parameter class: one registration line per family."""

from __future__ import annotations

from typing import Annotated, Union

from pydantic import Field

from . import vicsek_presets  # noqa: F401  (registers the M1 presets)
from .catalog import MODELS
from .couzin import CouzinParams  # noqa: F401  (registers Couzin)
from .couzin_presets import couzin_2002_torus  # noqa: F401  (its presets)
from .cucker_smale import CuckerSmaleParams  # noqa: F401  (registers Cucker-Smale)
from .cucker_smale_presets import cucker_smale_2007  # noqa: F401  (its preset)
from .flocking import FlockingParams  # noqa: F401  (registers M2)
from .flocking_presets import tjp_fixed  # noqa: F401  (registers the M2 and M3 presets)
from .formation import FormationParams  # noqa: F401  (registers M4)
from .formation_presets import sim1  # noqa: F401  (registers the M4 presets)
from .obstacles import ObstacleFlockingParams  # noqa: F401  (registers M3)
from .olfati_saber import OlfatiSaberParams  # noqa: F401  (registers Olfati-Saber)
from .olfati_saber_presets import olfati_saber_alg1  # noqa: F401  (its presets)
from .vicsek import VicsekParams

# The discriminated union of model parameter blocks, in registration order.
ModelSpec = Annotated[Union[tuple(MODELS.values())], Field(discriminator="kind")]  # noqa: UP007

__all__ = ["MODELS", "ModelSpec", "VicsekParams"]
