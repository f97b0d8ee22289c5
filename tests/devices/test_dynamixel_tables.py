"""Dynamixel model lookup (hwbridge.devices.dynamixel.tables) and what its callers report."""

from __future__ import annotations

import pytest

from hwbridge.devices.dynamixel import (
    MODELS,
    EmulatedDynamixelBus,
    UnknownModelError,
    UnknownRegisterError,
    find_model,
)
from hwbridge.errors import HwBridgeError


@pytest.mark.parametrize("key", ["XL999-W1", "ax12", 4242, " 4242 "])
def test_an_unknown_model_names_the_key_and_lists_the_known_models(key: str | int) -> None:
    with pytest.raises(UnknownModelError) as info:
        find_model(key)
    error = info.value
    assert isinstance(error, HwBridgeError)
    assert not isinstance(error, UnknownRegisterError)  # a model is not a register
    text = str(error)
    assert str(key).strip() in text
    assert all(name in text for name in MODELS), text


@pytest.mark.parametrize("key", [None, 12.5, ["XL430-W250"]])
def test_a_model_key_of_the_wrong_kind_is_an_unknown_model(key: object) -> None:
    with pytest.raises(UnknownModelError, match="known: XL430-W250"):
        find_model(key)  # type: ignore[arg-type]


@pytest.mark.parametrize("key", ["xl430-w250", "XL430W250", " AX-12A", 1060, "1060", 12])
def test_known_models_by_any_spelling_or_number(key: str | int) -> None:
    assert find_model(key).name in MODELS


def test_an_emulated_bus_with_an_unknown_model_says_which_servo() -> None:
    config = {
        "protocol": 2,
        "servos": [{"id": 1, "model": "XL430-W250"}, {"id": 3, "model": "XL9"}],
    }
    with pytest.raises(UnknownModelError) as info:
        EmulatedDynamixelBus.from_config(config, name="arm")
    text = str(info.value)
    assert text.startswith("emulated Dynamixel bus arm: servo 3: unknown Dynamixel model 'XL9'")
    assert "known: XL430-W250, XM430-W350, XM430-W210, AX-12A" in text
    assert "Error(" not in text  # no exception repr in a user's message
