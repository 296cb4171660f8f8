"""The ROS 2 tests' router (a Zenoh router on loopback standing in for ``rmw_zenohd``)."""

from __future__ import annotations

import pytest


@pytest.fixture
def router():
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    pytest.importorskip("rosbags", reason="rosbags is not installed")
    from _ros2live import Router

    r = Router()
    yield r
    r.close()
