"""The base class of every effect of a time step (``lbmpipe.assemble`` explains the model): a
module of its own that imports nothing of the package, so that every effect, in the fluid and
the particle packages alike, can import it without importing the assembly."""

from __future__ import annotations


class Effect:
    """One piece of physics in the time step. Subclasses set ``name``, ``phase`` and ``__call__``."""

    name = "effect"
    phase = "pre"
    #: key of the effect's tallies in ``Simulation.records()`` (None: it keeps none)
    record_key: str | None = None

    def __call__(self, sim) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def record(self) -> dict | None:
        """The effect's tallies since the start of the run (lattice units), or None."""
        return None

    def __repr__(self) -> str:
        return f"<{self.phase}: {self.name}>"
