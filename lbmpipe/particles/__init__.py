"""Rigid particles in the fluid: shapes, rigid-body motion, placement and packing, the coupling to
the fluid, contact geometry and the impulse collisions."""
