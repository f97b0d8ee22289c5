"""Zenoh config files pass through: the user/password arrangement from docs/graph.md."""

from __future__ import annotations

from pathlib import Path

import pytest

from hwbridge.cli import main
from hwbridge.errors import HwBridgeError
from hwbridge.graph import Graph, GraphConfig, ParamServer
from tests.netutil import free_port

ROUTER = """{{
  listen: {{ endpoints: ["tcp/127.0.0.1:{port}"] }},
  scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }},
  transport: {{ auth: {{ usrpwd: {{ user: "bridge", password: "bridge-secret",
                                  dictionary_file: "{users}" }} }} }},
}}"""
CLIENT = """{{
  connect: {{ endpoints: ["tcp/127.0.0.1:{port}"] }},
  scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }},
  transport: {{ auth: {{ usrpwd: {{ user: "lab", password: "{password}" }} }} }},
}}"""


def test_user_password_from_config_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    port = free_port()
    users = tmp_path / "users.txt"
    users.write_text("lab:lab-secret\nbridge:bridge-secret\n")
    router_file = tmp_path / "router.json5"
    router_file.write_text(ROUTER.format(port=port, users=users))
    good = tmp_path / "client.json5"
    good.write_text(CLIENT.format(port=port, password="lab-secret"))
    bad = tmp_path / "bad.json5"
    bad.write_text(CLIENT.format(port=port, password="guess"))

    with Graph(GraphConfig.from_file(router_file, "router", domain="auth")) as router:
        ParamServer(router, {"/secret/answer": 42})
        with Graph(GraphConfig.from_file(good, "client", domain="auth")) as client:
            assert client.params.get("/secret/answer") == 42
        with pytest.raises(HwBridgeError, match="cannot join the graph") as refused:
            Graph(GraphConfig.from_file(bad, "client", domain="auth"))
        # A refused login looks like no bridge at all to Zenoh: the hint names the file too.
        assert f"check that the credentials or certificates in {bad}" in str(refused.value)

        monkeypatch.delenv("HWBRIDGE_ENDPOINT", raising=False)
        monkeypatch.setenv("HWBRIDGE_DOMAIN", "auth")
        assert main(["--zenoh-config", str(good), "param", "get", "/secret/answer"]) == 0
        assert capsys.readouterr().out == "42\n"
        monkeypatch.setenv("HWBRIDGE_ZENOH_CONFIG", str(bad))
        assert main(["param", "get", "/secret/answer"]) == 1
        assert "cannot join the graph" in capsys.readouterr().err
