"""On-rig experiments: Chapter IV of the thesis run on the emulated rig (plant, controller, DSP).

| name | thesis | module |
| --- | --- | --- |
| ``verify`` | §4.1.1, §4.1.2 | :mod:`.verify` |
| ``pi-spectrogram`` | §4.2.2 | :mod:`.pi_spectrogram` |
| ``battery`` | §4.2.3 | :mod:`.battery` |
| ``reduced-damping`` | §4.4 | :mod:`.reduced_damping` |
| ``id-lag`` | §5.3 (future work) | :mod:`.id_lag` |
| ``noise-vs-lag`` | §5.3 (future work) | :mod:`.noise_vs_lag` |

Every experiment runs the rig through :class:`workbench.hil.HilRig` (its runs as
:class:`workbench.rig_spec.RigSpec` on the campaign engine, :mod:`workbench.campaign.rigs`): by default as the
one-thread co-simulation (:mod:`workbench.cosim`, bit-identical to the
three-process rig in lockstep); ``--mode lockstep`` starts the full
three-process rig (``--mode realtime`` on the wall clock), where ``--quick``
runs shorter stretches in one process (:mod:`workbench.composition`).
"""
