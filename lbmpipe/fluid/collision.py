"""The collision operator as one value: which operator relaxes the populations and at which rates.

A scene names the operator (``numerics.collision``) and, for TRT, its magic parameter
(``numerics.trt_magic``); :func:`lbmpipe.units.derive` turns them and the viscosity into one
:class:`Relaxation` (operator, ``omega``, ``omega_minus``); the assembly hands that value to the
sweep (``fluid.effects.StreamCollide``), whose kernel spec carries the operator and whose kernel
call carries the rates. A new operator is a member here, its rates in :meth:`Relaxation.from_tau`
and its arithmetic in ``fluid.kernels.render``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

#: With half-way bounce-back, the Poiseuille profile is exact when the "magic" product
#: Lambda = (tau_+ - 1/2)(tau_- - 1/2) equals 3/16 (Ginzburg); for BGK Lambda = (tau - 1/2)^2.
MAGIC_EXACT_WALL = 3.0 / 16.0


class CollisionOperator(enum.StrEnum):
    """The collision operators the generated sweep implements (the value is the scene's name)."""

    #: Single relaxation time, Eq. (2): every moment relaxes at ``omega = 1 / tau``; the paper's.
    BGK = "bgk"
    #: Two relaxation times: even moments at ``omega`` (sets the viscosity), odd moments at
    #: ``omega_minus``, chosen through the magic parameter so that the bounce-back wall position
    #: does not depend on tau.
    TRT = "trt"


def trt_omega_minus(tau: float, magic: float = MAGIC_EXACT_WALL) -> float:
    """TRT odd-moment relaxation rate ``1 / tau_-`` for the even-moment ``tau`` (viscosity) and the
    magic parameter ``Lambda = (tau - 1/2)(tau_- - 1/2)``."""
    return 1.0 / (magic / (tau - 0.5) + 0.5)


@dataclass(frozen=True)
class Relaxation:
    """One collision operator with its rates (lattice units, per step).

    ``omega`` is the even-moment (viscous) rate ``1 / tau``; ``omega_minus`` the odd-moment rate,
    equal to ``omega`` for BGK. Invariant: ``omega_minus == omega`` whenever ``operator`` is BGK."""

    operator: CollisionOperator
    omega: float
    omega_minus: float

    @classmethod
    def from_tau(cls, operator, tau: float, magic: float = MAGIC_EXACT_WALL) -> "Relaxation":
        """The operator's rates for relaxation time ``tau``; ``magic`` is used by TRT only."""
        op = CollisionOperator(operator)
        omega = 1.0 / tau
        return cls(op, omega, trt_omega_minus(tau, magic) if op is CollisionOperator.TRT else omega)

    @classmethod
    def of(cls, operator, omega: float, omega_minus: float | None = None) -> "Relaxation":
        """Rates given directly (tests, benchmarks); ``omega_minus`` defaults to ``omega``."""
        op = CollisionOperator(operator)
        return cls(op, float(omega), float(omega if omega_minus is None else omega_minus))
