"""User simulation (paper section 5.1): a simulated user as tables over the whole state space.

Pure: no I/O. A ``UserSimulator`` holds, for every turn state of ``core.mdp``:

* ``p_success[s]``: the performance model P(success | s);
* ``engagement[s, o]``: the engagement model Phi(s, o) in [0, 1] for outcome o (0 failure, 1 success);
* per-level quantiles of reaction and completion times (seconds from the beep), sampled by
  inverse-CDF interpolation.

Fitting from data lives in ``core.usermodel`` / ``nao_trainer.learn.fitting``; files in
``nao_trainer.learn.artifacts``. Tables make simulation a lookup, which is what lets training vectorise.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nao_trainer.core import mdp
from nao_trainer.files import JsonFormat

#: Probability levels of the stored time quantiles (0, 0.05, ..., 1).
TIME_QUANTILES = np.linspace(0.0, 1.0, 21)
FORMAT_VERSION = 1
#: The simulator file's header (checked by ``from_dict``; pure: files.JsonFormat only compares dicts here).
SIMULATOR_FILE = JsonFormat("nao-trainer/user-simulator", FORMAT_VERSION, "user simulator", "simulator")


class DefinitionMismatch(ValueError):
    """A simulator made for another state/action definition than ``core.mdp.DEFINITION`` (refit it)."""


#: Significant digits of the table values that enter the fingerprint. A refit on another machine
#: (or with another BLAS thread count) differs in the last bits only; 9 digits ignore that noise
#: while any real change of a model (a refit on other data, an edit) still changes the fingerprint.
FINGERPRINT_DIGITS = 9
#: Values closer to zero than this count as zero in the fingerprint (noise has no relative scale there).
_FINGERPRINT_ZERO = 1e-12


def fingerprint_text(values: np.ndarray) -> str:
    """The values as text rounded to ``FINGERPRINT_DIGITS`` significant digits (near-zeros as 0)."""
    v = np.asarray(values, dtype=float).ravel()
    v = np.where(np.abs(v) < _FINGERPRINT_ZERO, 0.0, v)
    return ",".join(np.char.mod(f"%.{FINGERPRINT_DIGITS}g", v).tolist())


@dataclass(frozen=True, eq=False)
class UserSimulator:
    """A simulated user. ``name`` is e.g. ``"cluster-1"``; ``metadata`` is free-form JSON data."""

    name: str
    p_success: np.ndarray  # (108,)
    engagement: np.ndarray  # (108, 2)
    reaction_quantiles: np.ndarray  # (4, len(TIME_QUANTILES)), per level
    completion_quantiles: np.ndarray  # (4, len(TIME_QUANTILES)), per level
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for attr, shape in (
            ("p_success", (mdp.N_TURN_STATES,)),
            ("engagement", (mdp.N_TURN_STATES, 2)),
            ("reaction_quantiles", (4, len(TIME_QUANTILES))),
            ("completion_quantiles", (4, len(TIME_QUANTILES))),
        ):
            value = np.array(getattr(self, attr), dtype=float)
            if value.shape != shape:
                raise ValueError(f"{self.name}: {attr} must have shape {shape}, got {value.shape}")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{self.name}: {attr} has non-finite values")
            value.setflags(write=False)
            object.__setattr__(self, attr, value)
        for attr in ("p_success", "engagement"):
            value = getattr(self, attr)
            if value.min() < 0 or value.max() > 1:
                raise ValueError(f"{self.name}: {attr} must lie in [0, 1], got {value.min():.3g}..{value.max():.3g}")
        for attr in ("reaction_quantiles", "completion_quantiles"):
            value = getattr(self, attr)
            if value.min() < 0 or np.any(np.diff(value, axis=1) < 0):
                raise ValueError(f"{self.name}: {attr} must be non-negative and non-decreasing per level")
        rest = self.metadata.get("rest_engagement")
        if rest is not None and not (isinstance(rest, (int, float)) and not isinstance(rest, bool) and 0 <= rest <= 1):
            raise ValueError(f"{self.name}: metadata.rest_engagement must be a number in [0, 1], got {rest!r}")

    # -- simulation ---------------------------------------------------------------------------

    def sample_success(self, state: int, rng: np.random.Generator) -> bool:
        """Draw the outcome of a turn played in turn state ``state``."""
        return bool(rng.random() < self.p_success[state])

    def engagement_of(self, state: int, success: bool) -> float:
        """Phi(state, outcome): the turn's expected normalised engagement."""
        return float(self.engagement[state, int(success)])

    def rest_engagement(self) -> float:
        """The engagement the participant shows at rest (greeting and instructions, before any turn).

        ``metadata["rest_engagement"]`` when the model file gives one, else the model's lowest task
        engagement (over every state and outcome): the index beta / (alpha + theta) rises with task
        demands and alpha is strongest at rest (Pope et al. 1995), so rest sits at or below the least
        engaging turn. A simulated Muse streams it during the baseline phase.
        """
        rest = self.metadata.get("rest_engagement")
        return float(self.engagement.min()) if rest is None else float(rest)

    def sample_times(self, level: int, rng: np.random.Generator) -> tuple[float, float]:
        """(reaction, completion) seconds from the beep, drawn from the level's distributions."""
        u = rng.random(2)
        rt = float(np.interp(u[0], TIME_QUANTILES, self.reaction_quantiles[level - 1]))
        ct = float(np.interp(u[1], TIME_QUANTILES, self.completion_quantiles[level - 1]))
        return rt, max(rt, ct)

    # -- identity and serialisation -------------------------------------------------------------

    def fingerprint(self) -> str:
        """SHA-256 of the tables rounded to ``FINGERPRINT_DIGITS`` significant digits.

        Policies record it so they are never used with another user model; the rounding keeps a
        refit that differs only by float noise from invalidating every trained policy.
        """
        h = hashlib.sha256(mdp.DEFINITION.encode())
        for table in (self.p_success, self.engagement, self.reaction_quantiles, self.completion_quantiles):
            h.update(b"|" + fingerprint_text(table).encode())
        return h.hexdigest()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (floats round-trip exactly through ``json``)."""
        return {
            **SIMULATOR_FILE.header(),
            "name": self.name,
            "mdp_definition": mdp.DEFINITION,
            "state_encoding": "p_success[i] and engagement[i] are for core.mdp.decode(i) = (L, RF, PR)",
            "time_quantiles": TIME_QUANTILES.tolist(),
            "p_success": self.p_success.tolist(),
            "engagement": self.engagement.tolist(),
            "reaction_quantiles": self.reaction_quantiles.tolist(),
            "completion_quantiles": self.completion_quantiles.tolist(),
            "fingerprint": self.fingerprint(),
            "metadata": self.metadata,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "simulator") -> "UserSimulator":
        """Rebuild from ``to_dict`` output; ValueError naming ``source`` on any mismatch."""
        SIMULATOR_FILE.check(data, source, ValueError)
        if data.get("mdp_definition") != mdp.DEFINITION:
            raise DefinitionMismatch(f"{source}: made for another state/action definition")
        try:
            sim = cls(
                name=str(data["name"]),
                p_success=np.asarray(data["p_success"], dtype=float),
                engagement=np.asarray(data["engagement"], dtype=float),
                reaction_quantiles=np.asarray(data["reaction_quantiles"], dtype=float),
                completion_quantiles=np.asarray(data["completion_quantiles"], dtype=float),
                metadata=dict(data.get("metadata", {})),
            )
        except KeyError as exc:
            raise ValueError(f"{source}: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:  # a text or a nested list where a table of numbers belongs
            raise ValueError(f"{source}: the tables (p_success, engagement, quantiles) must hold numbers ({exc})") from None
        if "fingerprint" in data and data["fingerprint"] != sim.fingerprint():
            raise ValueError(f"{source}: tables do not match their fingerprint (file altered or torn)")
        return sim

    @classmethod
    def from_level_rates(
        cls,
        name: str,
        success_by_level: "list[float] | np.ndarray",
        engagement_by_level: "list[float] | np.ndarray" = (0.5, 0.5, 0.5, 0.5),
        reaction_s: "tuple[float, float]" = (0.8, 2.5),
        seconds_per_letter: "tuple[float, float]" = (0.6, 1.2),
    ) -> "UserSimulator":
        """A simple simulator from per-level rates (no dependence on feedback or previous result).

        Used by the demo and by tests until a data-driven simulator is chosen. Times are uniform
        between the given bounds; completion adds ``seconds_per_letter`` per letter.
        """
        p = np.asarray(success_by_level, dtype=float)
        e = np.asarray(engagement_by_level, dtype=float)
        if p.shape != (4,) or e.shape != (4,):
            raise ValueError("success_by_level and engagement_by_level need 4 values (levels 1..4)")
        levels = mdp.LEVEL - 1
        rt = np.tile(np.linspace(*reaction_s, len(TIME_QUANTILES)), (4, 1))
        per_letter = np.linspace(*seconds_per_letter, len(TIME_QUANTILES))
        ct = rt + np.outer([3, 5, 7, 9], per_letter)
        return cls(
            name=name,
            p_success=p[levels],
            engagement=np.repeat(e[levels][:, None], 2, axis=1),
            reaction_quantiles=rt,
            completion_quantiles=ct,
            metadata={"kind": "per-level rates"},
        )
