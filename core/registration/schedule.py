"""The α/β/γ schedule of Allen et al. 2003: a low- then a high-resolution pass in four stages."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class Stage:
    """One stage: weights of the data (α), smoothness (β) and marker (γ) terms.

    ``max_iterations`` correspondence updates at most; the stage ends earlier once no vertex moves
    more than ``tolerance_m`` (metres) between two updates.
    """

    alpha: float
    beta: float
    gamma: float
    resolution: Literal["low", "high"]
    max_iterations: int = 20
    tolerance_m: float = 2e-4


@dataclass(frozen=True)
class Schedule:
    """An ordered list of stages (low-resolution stages must come first).

    An empty schedule keeps the body prior's result without per-vertex refinement.
    """

    stages: tuple[Stage, ...]

    @classmethod
    def paper(cls) -> Schedule:
        """The paper's schedule: (0,1,10), (1,1,10) at low res; (1,1,10), (10,1,1) at high res."""
        return cls(
            stages=(
                Stage(0.0, 1.0, 10.0, "low", max_iterations=1),
                Stage(1.0, 1.0, 10.0, "low", max_iterations=25, tolerance_m=3e-4),
                Stage(1.0, 1.0, 10.0, "high", max_iterations=8, tolerance_m=2e-4),
                Stage(10.0, 1.0, 1.0, "high", max_iterations=8, tolerance_m=1e-4),
            )
        )

    @classmethod
    def refine(cls) -> Schedule:
        """Default after the body prior: the paper's final full-resolution stage, markers weak.

        The body prior (``core.registration.shape_prior``) has already brought the template to
        the subject's shape and posture using the markers; measured on simulated scans, the
        paper's marker-heavy low-resolution stages then add error (placement noise of the
        markers is pulled into the surface), while this stage fits the scan's detail.
        """
        return cls(stages=(Stage(10.0, 1.0, 0.1, "high", max_iterations=8, tolerance_m=1e-4),))

    @classmethod
    def fast(cls) -> Schedule:
        """A short refinement for tests and previews (fewer iterations, same weights)."""
        return cls(stages=(Stage(10.0, 1.0, 0.1, "high", max_iterations=3, tolerance_m=3e-4),))

    @classmethod
    def paper_fast(cls) -> Schedule:
        """The paper's four stages with fewer iterations (tests of the plain method)."""
        return cls(
            stages=(
                Stage(0.0, 1.0, 10.0, "low", max_iterations=1),
                Stage(1.0, 1.0, 10.0, "low", max_iterations=6, tolerance_m=5e-4),
                Stage(1.0, 1.0, 10.0, "high", max_iterations=2, tolerance_m=5e-4),
                Stage(10.0, 1.0, 1.0, "high", max_iterations=2, tolerance_m=3e-4),
            )
        )

    def __post_init__(self) -> None:
        seen_high = False
        for st in self.stages:
            if min(st.alpha, st.beta, st.gamma) < 0:
                raise ValueError(f"stage weights must be ≥ 0, got {st}")
            if st.max_iterations < 1:
                raise ValueError(f"max_iterations must be ≥ 1, got {st}")
            if st.resolution == "high":
                seen_high = True
            elif seen_high:
                raise ValueError("low-resolution stages must precede high-resolution ones")


PRESETS = ("default", "fast", "paper")


def preset(name: str) -> dict[str, object]:
    """Keyword options of :func:`core.registration.fit.fit` for a named preset.

    - ``default``: the body prior, then :meth:`Schedule.refine` (best accuracy, measured).
    - ``fast``: the body prior, then :meth:`Schedule.fast` (previews, tests).
    - ``paper``: the paper's method as published: :meth:`Schedule.paper` from the bare template.
    """
    if name == "default":
        return {"schedule": Schedule.refine(), "shape_prior": True}
    if name == "fast":
        return {"schedule": Schedule.fast(), "shape_prior": True}
    if name == "paper":
        return {"schedule": Schedule.paper(), "shape_prior": False}
    raise ValueError(f"unknown schedule preset {name!r}; choose one of {', '.join(PRESETS)}")
