"""Ray, the optional extra (``pip install .[ray]``) that spreads sweeps and
the tracing of large scenes over worker processes or a cluster.

Everything that imports ``ray`` goes through ``ray_module()``, so a missing
extra is a one-line error naming the install command, never a traceback.
``connect()`` starts a local Ray in-process (bound to loopback, no dashboard,
no usage reporting) or joins the cluster at an address; an already running
Ray in this process (a test session's, an earlier call's) is reused.
"""

from __future__ import annotations

import os
import sys

INSTALL_HINT = ("Ray is not installed; install the optional extra: pip install 'gamma-weathering[ray]' "
                "(from a source tree: pip install '.[ray]')")

#: Shared memory Ray may use for objects when it is started here (bytes):
#: enough for a few iterations' surfel state and a sweep's outputs in flight,
#: far below Ray's default of 30% of the machine's memory.
LOCAL_OBJECT_STORE = 1 << 30


class RayUnavailable(RuntimeError):
    """Ray is missing or cannot be reached; the message says what to do."""


def _loopback_only() -> None:
    """Make a Ray started here use 127.0.0.1 as its node address (Ray's own
    switch for single-machine use), so nothing is addressed beyond loopback."""
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    constants = sys.modules.get("ray._private.ray_constants")
    if constants is not None:       # Ray already imported: it read the switch then
        constants.ENABLE_RAY_CLUSTER = False


def ray_module():
    try:
        import ray
    except ImportError:
        raise RayUnavailable(INSTALL_HINT) from None
    return ray


def available() -> bool:
    try:
        ray_module()
    except RayUnavailable:
        return False
    return True


class Connection:
    """A Ray session: ``close()`` shuts down only a Ray this object started."""

    def __init__(self, ray, started: bool):
        self.ray, self.started = ray, started

    def close(self) -> None:
        if self.started and self.ray.is_initialized():
            self.ray.shutdown()
        self.started = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def connect(address: str | None = None, num_cpus: int | None = None) -> Connection:
    """Join the cluster at ``address``, or start a local Ray on loopback."""
    ray = ray_module()
    if ray.is_initialized():
        return Connection(ray, started=False)
    if not address:
        _loopback_only()
    # No usage statistics sent anywhere, and quiet start-up.
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    # A local start waits 30 s (fixed in Ray) for its raylet; on a machine
    # busy enough to miss that, another try usually makes it.
    attempts = 1 if address else 3
    for attempt in range(attempts):
        try:
            if address:
                ray.init(address=address, logging_level="ERROR", configure_logging=True)
            else:
                ray.init(num_cpus=num_cpus, include_dashboard=False,
                         object_store_memory=LOCAL_OBJECT_STORE, logging_level="ERROR",
                         configure_logging=True)
            break
        except Exception as err:     # Ray raises plain Exception for a start-up time-out
            ray.shutdown()           # also stops what a half-started node left running
            if attempt + 1 == attempts:
                where = f"the Ray cluster at '{address}'" if address else "a local Ray"
                raise RayUnavailable(f"cannot start or reach {where}: {err}") from None
    return Connection(ray, started=True)
