"""Every JSON message key of the contract has a model in the recorder, so a
recorded run never files a valid message under ``/_undecodable``."""

from __future__ import annotations

from protocol.keys import Keys
from workbench.recording.schemas import BATCH_SUFFIX, model_for_key

JSON_KEYS = (
    "flag",
    "interrupt",
    "dsp_config",
    "dsp_config_ack",
    "truth",
    "scenario",
    "plant_events",
    "controller_status",
    "controller_command",
    "tf_downloads",
)


def test_every_json_key_of_the_contract_has_a_model() -> None:
    keys = Keys("default")
    missing = [name for name in JSON_KEYS if model_for_key(getattr(keys, name)) is None]
    assert not missing, missing
    assert keys.batch.endswith(BATCH_SUFFIX) and model_for_key(keys.batch) is None  # batches are typed arrays
    assert model_for_key(keys.health("dsp")) is not None
