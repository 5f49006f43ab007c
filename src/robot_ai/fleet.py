"""The package's fleet engine: Ray, an optional extra (``pip install 'ray==2.60.0'``; never needed by ``make demo``).
No rospy.

A class graded across machines (robot_ai.grading.on_ray), the Q-learning learners (robot_ai.cartpole.q_learning) and
ARS's rollouts (robot_ai.ars) run as Ray tasks or actors when given a cluster's address: ``check_fk --ray ADDRESS``,
``--ray`` on the command lines, ``~ray_address`` on the nodes. Every machine of the cluster has the package installed
the same way (its venv and its catkin workspace at the same paths), so that a task imports what the caller imports.

    ray = connect('auto')          # the cluster this machine's `ray start` joined; or 'HOST:PORT', 'ray://HOST:PORT'
    cpus = cluster_cpus(ray)       # {node id: CPUs} of the nodes alive
"""
from __future__ import annotations

import importlib.util
import logging
import os

RAY_VERSION = '2.60.0'      # the release the package is tested with (requirements-ray.txt)
INSTALL = f"pip install 'ray=={RAY_VERSION}'"


class FleetError(RuntimeError):
    """Ray is not installed here, or the cluster cannot be reached; one line."""


def available() -> str:
    """'' when Ray can be imported here, else why not (one line)."""
    if importlib.util.find_spec('ray') is None:
        return f'Ray is not installed in this Python ({INSTALL} in the package\'s venv)'
    return ''


def connect(address: str):
    """The ray module, connected to the cluster at `address` ('auto': the one this machine joined with `ray start`;
    'HOST:PORT' of a head node; 'ray://HOST:PORT' through Ray Client). A process connects once; a second call with
    any address keeps the first connection. FleetError when Ray is missing or nothing answers at the address."""
    problem = available()
    if problem:
        raise FleetError(problem)
    if not address or not address.strip():
        raise FleetError('a Ray address is HOST:PORT of the head node, ray://HOST:PORT, or auto')
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')      # no usage report leaves the machine
    import ray
    if ray.is_initialized():
        return ray
    _reachable(address.strip())
    try:
        ray.init(address=address.strip(), logging_level=logging.WARNING, log_to_driver=False,
                 configure_logging=True)
    except (ConnectionError, RuntimeError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise FleetError(f'no Ray cluster at {address} ({first}); start one with `ray start --head` (see '
                         f'docs/fleet.md)') from None
    return ray


def _reachable(address: str, seconds: float = 5.0) -> None:
    """FleetError unless something listens at HOST:PORT (ray.init would retry an address where nothing answers for
    minutes); 'auto' and anything else are left to ray.init."""
    import socket
    host, _, port = address.removeprefix('ray://').rpartition(':')
    if not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip('[]'), int(port)), timeout=seconds).close()
    except OSError as e:
        raise FleetError(f'no Ray cluster at {address} ({e.strerror or e}); start one with `ray start --head` (see '
                         f'docs/fleet.md)') from None


def cluster_cpus(ray) -> dict[str, float]:
    """{node id: CPUs} of the cluster's nodes that are alive (a node that gives no CPU is left out)."""
    out = {}
    for node in ray.nodes():
        cpus = float(node.get('Resources', {}).get('CPU', 0.0))
        if node.get('Alive') and cpus > 0:
            out[node['NodeID']] = cpus
    return out
