"""What the ROS 2 tests share: zenoh-ros2-sdk, the independent rmw_zenoh implementation they
check against, made to read this package's ``.msg`` definitions and never download."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from services.ros2 import messages
from tests.ros2.samples import write_definitions


@pytest.fixture
def sdk_registry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """zenoh-ros2-sdk's message registry on this package's ``.msg`` files, its git download
    replaced by a failure that the test sees (the registry swallows exceptions)."""
    from zenoh_ros2_sdk import message_registry

    folder = tmp_path / "msg"
    write_definitions(folder, messages.EXPOSED_TYPES)
    downloads: list[str] = []

    def no_download(package: str) -> None:
        downloads.append(package)
        raise RuntimeError(f"offline: no download of {package}")

    monkeypatch.setattr(message_registry, "get_repository_for_package", no_download)
    yield message_registry.MessageRegistry(str(folder))
    assert downloads == [], f"zenoh-ros2-sdk tried to download {downloads}"


@pytest.fixture
def sdk(sdk_registry: Any, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """zenoh-ros2-sdk as a whole on that registry, its session config the bundled rmw_zenoh one
    (loopback) without environment overrides; its shared session closed after the test."""
    from zenoh_ros2_sdk import message_registry
    from zenoh_ros2_sdk.session import ZenohSession

    monkeypatch.delenv("ZENOH_SESSION_CONFIG_URI", raising=False)
    monkeypatch.delenv("ZENOH_CONFIG_OVERRIDE", raising=False)
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    monkeypatch.setattr(message_registry, "_registry", sdk_registry)
    yield
    if ZenohSession._instance is not None:
        ZenohSession._instance.close()
        ZenohSession._instance = None
