"""The compose file's zenoh router serves the REST API on 8000 with a
memory storage of health and status, so a plain HTTP GET on
``/ralf/default/health/**`` has something to answer (checked as far as a
machine without a Docker engine allows: the config parses as a zenoh
config and its storages cover the keys the services publish)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml
import zenoh

from protocol.keys import SERVICES, Keys
from service_kit.access import router_config

ROOT = Path(__file__).resolve().parents[2]


def test_router_runs_the_rest_plugin_on_8000_with_its_generated_config_mounted(tmp_path: Path) -> None:
    router = yaml.safe_load((ROOT / "docker-compose.yml").read_text())["services"]["zenoh-router"]
    cmd = router["command"]
    assert cmd[cmd.index("--rest-http-port") + 1] == "8000"
    assert "8000:8000" in router["ports"]
    config_in_container = cmd[cmd.index("-c") + 1]
    (mount,) = [v for v in router["volumes"] if config_in_container.startswith(v.split(":")[1])]
    # `ralf-hil credentials --out secrets` writes the file the router mounts
    assert subprocess.run([sys.executable, "-m", "workbench", "credentials", "--out", str(tmp_path)], check=False).returncode == 0
    assert (tmp_path / Path(config_in_container).name).is_file(), mount


def test_router_storages_cover_health_and_status() -> None:
    import json

    config = zenoh.Config.from_json5(json.dumps(router_config(Keys("default"), "/etc/ralf/zenoh-credentials.txt")))
    plugins = json.loads(config.get_json("plugins"))
    assert plugins["rest"]["http_port"] == 8000
    storages = [zenoh.KeyExpr(s["key_expr"]) for s in plugins["storage_manager"]["storages"].values()]
    keys = Keys("default")
    for key in [keys.health(s) for s in SERVICES] + [keys.controller_status]:
        assert any(s.intersects(zenoh.KeyExpr(key)) for s in storages), key
    query = zenoh.KeyExpr("ralf/default/health/**")  # what the documented curl asks
    assert any(s.intersects(query) for s in storages)
    assert not any(s.intersects(zenoh.KeyExpr(keys.batch)) for s in storages)  # batches are not stored
