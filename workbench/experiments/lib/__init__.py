"""Analysis the experiments share, one topic a module: pure functions of run records and arrays."""
