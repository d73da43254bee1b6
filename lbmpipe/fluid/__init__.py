"""The lattice Boltzmann fluid: lattices, the generated stream-and-collide kernels,
wall boundaries and the observables of the populations. Depends on nothing else in lbmpipe (but
its cache folder, ``lbmpipe.cache_root``)."""
