"""Offline experiments: the thesis's analytic figures and the §4.3 simulation (no rig, deterministic).

| name | thesis | module |
| --- | --- | --- |
| ``oatf-response`` | §3.3 Figs. 3.7-3.8, Fig. 4.8 | :mod:`.oatf_response` |
| ``fwhm-error`` | App. B, Fig. B.1 | :mod:`.fwhm_error` |
| ``vrm`` | App. C, Figs. C.1-C.6 | :mod:`.vrm` |
| ``simulation`` | §4.3 | :mod:`.simulation` |
"""
