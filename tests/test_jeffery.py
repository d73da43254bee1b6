"""Jeffery orbit of a free L/D = 2 cylinder in simple shear (issue 44, validation item 4), small:
``lbmpipe.reproduction.jeffery`` (setup and reference there), ``benchmarks/jeffery.py`` full size.

Over a quarter orbit the axis turns from along the flow (slowest) to across it (fastest); Jeffery's
``dphi/dt = gamma (r^2 cos^2 phi + sin^2 phi) / (r^2 + 1)`` makes the ratio of the two rates
``r_e^2``, so the equivalent aspect ratio follows from the rates alone, without the shear rate.
D = 6 in a 36 x 36 x 30 box (6 diameters between the walls and along the flow), Re_p = 0.5 to keep
the quarter orbit short (2,600 steps). Measured (tau 1): ``sqrt(rate ratio)`` 1.956 with the
paper's method, 2.001 with the accurate one, against ``r_e = 1.914`` (+2.2 %, +4.5 %); the rate
across the flow within 1 % of Jeffery's, along it -3.4 % and -8.3 %. Tolerance: ``r`` within 6 %,
the measured spread plus the reference's uncertainty at this ratio (Zhang's fit against the other
estimates, module docstring); 6 % in ``r`` is 3.4 % in the period, inside the issue's 5 %. A
sphere (ratio 1) or a cylinder turning at the vorticity's rate fails it.
"""

import math

import pytest

from lbmpipe.reproduction import jeffery as jf


@pytest.mark.parametrize("method", ["paper", "accurate"])
def test_cylinder_tumbles_faster_across_the_flow_than_along_it_by_jefferys_equivalent_ratio_squared(method):
    run = jf.sheared_cylinder(6.0, (36, 36, 30), tau=1.0, re_p=0.5, method=method, phi0=0.5 * math.pi - 0.3,
                              turn=0.5 * math.pi + 0.35)
    g = run["gamma"]
    along, across = jf.rate_at(run, 0.5 * math.pi) / g, jf.rate_at(run, math.pi) / g
    r = math.sqrt(across / along)
    ref_along, ref_across = jf.jeffery_rate(0.5 * math.pi, jf.R_E_ZHANG), jf.jeffery_rate(math.pi, jf.R_E_ZHANG)
    print(f"{method}: rate along {along:.4f}, across {across:.4f} (Jeffery {ref_along:.4f}, {ref_across:.4f}); "
          f"r = {r:.3f} against {jf.R_E_ZHANG:.3f}")
    assert r == pytest.approx(jf.R_E_ZHANG, rel=0.06)
    assert across == pytest.approx(ref_across, rel=0.03)
    assert abs(run["drift"]).max() < 0.05  # on the centre plane the cylinder stays put
