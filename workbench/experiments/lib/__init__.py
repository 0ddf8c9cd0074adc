"""Analysis the experiments share: each module named after what it computes."""
