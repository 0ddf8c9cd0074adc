"""``python -m plant_emulator.model.speed_probe`` ran the speed probe, which is now ``ralf-hil plant speed-probe``
(the measurement tools are the launcher's, not the service's): it names it and exits 2."""

from service_kit.moved import exit_moved

if __name__ == "__main__":
    exit_moved("python -m plant_emulator.model.speed_probe", "ralf-hil plant speed-probe")
