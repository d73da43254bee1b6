"""Errors shared across the layers: a bad scene (raised by the scene's validation and by
``units.derive``) and an unstable run (raised by the run-time guard and the collision step, caught
by the run loop)."""

from __future__ import annotations


class Unstable(RuntimeError):
    """A failed guard check: ``what`` failed, ``where`` (node or particle), at ``step``, the likely
    ``cause`` and a ``fix``. ``str()`` is the full one-paragraph message."""

    def __init__(self, what: str, where: str, step: int, cause: str, fix: str):
        self.what, self.where, self.step, self.cause, self.fix = what, where, int(step), cause, fix
        super().__init__(f"unstable at step {self.step}: {what} at {where}. Likely cause: {cause}. Fix: {fix}.")


class SceneError(ValueError):
    """A bad scene: ``field`` (dotted path), what is wrong, and how to fix it.

    ``str(err)`` is ``"scene error in <field>: <message>. Fix: <fix>"``. When several problems are
    found at once, ``errors`` lists them all (the first one also fills field/message/fix) and
    ``str(err)`` has one such line per problem.
    """

    def __init__(self, field: str, message: str, fix: str, errors: list["SceneError"] | None = None):
        self.field = field
        self.message = message.rstrip(".")
        self.fix = fix.rstrip(".")
        self.errors: list[SceneError] = list(errors) if errors else [self]
        super().__init__(str(self))

    def line(self) -> str:
        return f"scene error in {self.field}: {self.message}. Fix: {self.fix}"

    def __str__(self) -> str:
        return "\n".join(e.line() for e in self.errors)

    def __reduce__(self):
        return (SceneError, (self.field, self.message, self.fix, self.errors if len(self.errors) > 1 else None))

    @classmethod
    def combine(cls, errors: list["SceneError"]) -> "SceneError":
        flat = [e for err in errors for e in err.errors]
        first = flat[0]
        return cls(first.field, first.message, first.fix, flat if len(flat) > 1 else None)
