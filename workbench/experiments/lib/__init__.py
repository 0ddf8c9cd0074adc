"""Analysis the experiments share, one topic per module (delays after a step, ARX replays, dither costs, trajectories)."""
