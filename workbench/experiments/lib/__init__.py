"""Analysis the experiments share, one topic a module: pure functions of arrays and run records."""
