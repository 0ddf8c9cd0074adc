"""Analysis the experiments build on and a user can call: pure functions of arrays, one topic a module."""
