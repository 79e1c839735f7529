"""The staggered-pose model (paper sections 3 and 4.1, SPEC section 3).

* :mod:`.knots`: knots, layers and tracks, the representation in memory;
* :mod:`.kinds`: what differs between translations and rotations (⊕, ⊖, splines);
* :mod:`.segments`, :mod:`.bezier`, :mod:`.rotation_spline`, :mod:`.rotation_fit`:
  cubic spline segments of both kinds and their batched fits;
* :mod:`.fit`: fitting a track's splines and displacement maps to motion;
* :mod:`.evaluate`: a track's values (splines ⊕ displacement maps, layer over layer);
* :mod:`.restructure`: retiming and refitting knots while keeping the motion;
* :mod:`.timewarp`: piecewise-linear time warps;
* :mod:`.variables`: a clip's control variables as dense arrays;
* :mod:`.document`: the document (motion, poses, tracks, constraints) and its checks.
"""
