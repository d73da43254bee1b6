"""lbmpipe: lattice Boltzmann reproduction of Ku & Lin (cylinders and cubes in a crowded pipe flow)."""

__version__ = "0.1.0"
