"""Channel planning: backward exit search, per-node optimisation, spline fit, certification."""
