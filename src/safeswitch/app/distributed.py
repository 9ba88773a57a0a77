"""Ray, started or joined for a campaign, a sweep or a falsification, and stopped again.

``workers=N`` starts a local Ray cluster with ``N`` CPUs on this machine (``ray.init`` — what a
laptop has); ``address="host:port"`` joins an existing cluster (its head node's GCS address, as
``ray start --head`` prints it; every node needs safeswitch installed). ``workers=0`` runs every
task in this process, one after another, without Ray (for debugging, and where Ray is absent).
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

T = TypeVar("T")

#: How long joining an ``--address`` may take before it is reported unreachable [s].
CONNECT_TIMEOUT_S = 5.0


class DistributedError(RuntimeError):
    """Ray is missing or the cluster cannot be reached; the message says what to do."""


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise DistributedError(
            "Ray is not installed: install the extra with pip install 'safeswitch[ray]'"
        ) from exc
    return ray


#: The client connection preface of HTTP/2 (RFC 9113, 3.4) followed by an empty SETTINGS
#: frame: a Ray head's GCS is a gRPC server and answers it with a SETTINGS frame of its own.
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
#: Frame type of SETTINGS (the fourth byte of a frame header).
_SETTINGS = 4


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Raise :class:`DistributedError` unless a Ray head answers at ``address``
    (``host:port``) within ``timeout`` seconds: the TCP connection opens and the server
    speaks gRPC (HTTP/2), as a Ray head's GCS does. ``ray.init`` itself would retry an
    unreachable or foreign address for minutes, printing its client's log lines."""
    if address == "auto":
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise DistributedError(f"--address {address!r} is not host:port (e.g. 10.0.0.5:6379)")
    hint = "start one with `ray start --head` there, or leave out --address to run locally"
    try:
        with socket.create_connection((host.removeprefix("ray://"), int(port)), timeout) as conn:
            conn.settimeout(timeout)
            conn.sendall(_HTTP2_PREFACE)
            answer = conn.recv(9)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise DistributedError(
            f"cannot reach a Ray cluster at {address} within {timeout:.0f} s ({reason}); {hint}"
        ) from exc
    if len(answer) < 4 or answer[3] != _SETTINGS:
        raise DistributedError(
            f"no Ray cluster answers at {address} (another service does); {hint}"
        )


@dataclass
class Cluster:
    """Where tasks run: a Ray cluster (``ray`` set) or this process (``ray`` is ``None``).

    Attributes:
        ray: The ``ray`` module while a cluster is connected.
        cpus: CPUs the cluster offers (the workers of a local cluster).
        startup_s: Time to start or join the cluster [s] (reported apart from the work).
    """

    ray: Any
    cpus: int
    startup_s: float

    def map(
        self,
        function: Callable[..., T],
        arguments: Iterable[tuple[Any, ...]],
        on_result: Callable[[int, T], None],
        on_error: Callable[[int, BaseException], None],
        window: int | None = None,
    ) -> None:
        """``function(*args)`` for every ``args`` of ``arguments`` (the ``i``-th handed over as
        ``i``), in parallel on the cluster; results and failures are handed over as they
        arrive (one failed task does not stop the others).

        ``arguments`` is consumed lazily: at most ``window`` tasks (default: twice the
        cluster's CPUs) are submitted and not yet handed over at any time, so a campaign of
        any length holds a bounded number of tasks in memory, here and on the cluster.
        """
        if self.ray is None:
            for i, args in enumerate(arguments):
                try:
                    result = function(*args)
                except Exception as exc:
                    on_error(i, exc)
                else:
                    on_result(i, result)
            return
        ray = self.ray
        remote = ray.remote(num_cpus=1, max_retries=0)(function)
        limit = max(window if window is not None else 2 * self.cpus, 1)
        queued = enumerate(arguments)
        pending: dict[Any, int] = {}

        def submit() -> None:
            for i, args in queued:
                pending[remote.remote(*args)] = i
                if len(pending) >= limit:
                    return

        submit()
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                i = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # the task raised, or its worker died
                    on_error(i, exc)
                else:
                    on_result(i, result)
            submit()


@contextlib.contextmanager
def cluster(workers: int, address: str | None = None) -> Iterator[Cluster]:
    """A :class:`Cluster` for the duration of the block; a local cluster is shut down on the
    way out (also on an error or Ctrl-C), leaving no process behind."""
    import time

    if workers < 0:
        raise DistributedError(f"--workers must be >= 0, got {workers}")
    started = time.perf_counter()
    if address is None and workers == 0:
        yield Cluster(None, 1, 0.0)
        return
    ray = _import_ray()
    if address is not None:
        check_reachable(address)
    # Workers must not oversubscribe the cores: one thread per numeric library each.
    env = {name: "1" for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    runtime_env = {"env_vars": env}
    try:
        if address is not None:
            ray.init(
                address=address, runtime_env=runtime_env, log_to_driver=False,
                logging_level="ERROR",
            )  # fmt: skip
        else:
            ray.init(  # address="local": a new cluster, even where another one runs
                address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False,
                logging_level="ERROR", runtime_env=runtime_env,
                _temp_dir=os.environ.get("SAFESWITCH_RAY_TMP"),
            )  # fmt: skip
    except Exception as exc:
        raise DistributedError(f"Ray did not start: {exc}") from exc
    try:
        cpus = int(ray.cluster_resources().get("CPU", workers or 1))
        yield Cluster(ray, cpus, time.perf_counter() - started)
    finally:
        ray.shutdown()
