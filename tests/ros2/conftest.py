"""Every DDS participant of these tests stays on this machine: Cyclone bound to the loopback interface, no multicast,
discovery by unicast to 127.0.0.1, in a domain of this test run's own (the environment is set before any participant
exists; subprocesses inherit it)."""

from __future__ import annotations

import os

import pytest
from _live import DOMAIN, LOOPBACK


@pytest.fixture(scope="session", autouse=True)
def loopback_dds():
    saved = {k: os.environ.get(k) for k in ("CYCLONEDDS_URI", "ROS_DOMAIN_ID")}
    os.environ["CYCLONEDDS_URI"] = LOOPBACK
    os.environ["ROS_DOMAIN_ID"] = str(DOMAIN)
    yield DOMAIN
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
