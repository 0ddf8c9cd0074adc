"""``python -m dsp_service.bench`` ran the identification step's bench, which is now ``ralf-hil bench --only dsp``
(the measurement tools are the launcher's, not the service's): it names it and exits 2."""

from service_kit.moved import exit_moved

if __name__ == "__main__":
    exit_moved("python -m dsp_service.bench", "ralf-hil bench --only dsp")
