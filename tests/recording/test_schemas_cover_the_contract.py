"""Every JSON message key of the contract has a model in the recorder, and
every binary one (batches, TF snapshots) a codec, so a recorded run never
files a valid message under ``/_undecodable``."""

from __future__ import annotations

from protocol.encodings import BATCH_MIME, JSON_MIME, TF_MIME, mime_for
from protocol.keys import Keys
from protocol.rig_description import RIG
from workbench.recording.schemas import BATCH_SUFFIX, is_batch_key, is_tf_key, model_for_key

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
)


def test_every_json_key_of_the_contract_has_a_model() -> None:
    keys = Keys("default")
    missing = [name for name in JSON_KEYS if model_for_key(getattr(keys, name)) is None]
    assert not missing, missing
    assert keys.batch.endswith(BATCH_SUFFIX) and model_for_key(keys.batch) is None  # batches are typed arrays
    assert model_for_key(keys.health("dsp")) is not None


def test_binary_keys_are_typed_arrays_with_their_own_encoding() -> None:
    keys = Keys("default")
    for key in (keys.tf_downloads, keys.tf):
        assert model_for_key(key) is None and is_tf_key(key) and not is_batch_key(key)
        assert mime_for(key) == TF_MIME
    assert mime_for(keys.batch) == BATCH_MIME and is_batch_key(keys.batch)
    assert all(mime_for(getattr(keys, name)) == JSON_MIME and not is_tf_key(getattr(keys, name)) for name in JSON_KEYS)


def test_every_channel_of_the_description_is_covered() -> None:
    keys = Keys("default")
    for suffix, channel, _ in RIG.expanded():
        key = f"{keys.root}/{suffix}"
        if channel.payload == "tf":
            assert is_tf_key(key), suffix
        elif channel.payload == "batch":
            assert is_batch_key(key), suffix
        elif isinstance(channel.payload, type):
            assert model_for_key(key) is channel.payload, suffix
