"""Batch prediction on a Ray cluster (``stereojax predict INPUT... --out OUT --ray ADDRESS``): the
outputs, resume, ``--overwrite`` and summary of a local batch (:func:`stereojax.app.batch.predict_batch`),
with the frames spread over the cluster's workers.

* **Workers compile once.** Each worker is a Ray actor (:class:`FrameWorker`) that keeps its
  process, so the compiled chain of each size bucket (``stereojax.inference.predictor``'s cache, and the
  persistent compile cache on disk) and the loaded model serve every frame it gets. A worker asks
  for one GPU when the cluster has GPUs, else for ``cpus_per_worker`` CPUs.
* **Frames are tasks.** :class:`ray.util.ActorPool` hands the next frame to the next free worker
  (the cluster balances them; at most one frame per worker in flight: back-pressure). Each
  worker writes ``OUT/<frame>/`` itself (staging folder, then a rename): ``OUT`` must be a folder
  every node sees (a shared file system). The driver writes only ``summary.json``.
* **Faults.** A worker that dies mid-frame is restarted by Ray and the frame is retried
  (``max_restarts``, ``max_task_retries``); its half-written staging folder is removed when the
  batch ends. A killed driver leaves complete frame folders: the same command continues from
  them. A bad pair is one line, as locally. An unreachable cluster is one line
  (:class:`ClusterError`, exit code 9) before anything runs.

Ray is an optional dependency (``pip install "stereojax[ray]"``); this module imports it only
when called.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import Callable

from stereojax.app.batch import frame_work, predict_batch_locked, remove_stale
from stereojax.app.outputs import folder_lock, output_folder
from stereojax.data.io import write_json
from stereojax.errors import ClusterError
from stereojax.inference.compile_cache import enable

#: how often Ray restarts a dead worker, and retries the frame it held
MAX_RESTARTS = 4
MAX_TASK_RETRIES = 4
#: how long the workers may take to be placed and to start (importing JAX, loading the model)
PLACE_TIMEOUT_S = 300


def worker_resources(workers: int, gpus: int, cpus: int, cpus_per_worker: int = 2) -> dict:
    """What each of ``workers`` actors asks for, so that all of them fit the cluster at once: one
    GPU each when the cluster has GPUs (a share of one when there are more workers than GPUs),
    else ``cpus_per_worker`` CPUs, or the cluster's CPUs shared out when that is more than it has."""
    if gpus:
        return {"num_gpus": min(1.0, gpus / workers)}
    return {"num_cpus": min(float(cpus_per_worker), cpus / workers)}


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ClusterError('--ray needs the ray package: pip install "stereojax[ray]"') from None
    return ray


def _check_reachable(address: str, timeout_s: float = 3.0) -> None:
    """Refuse at once an address where nothing listens (ray.init would wait a long time)."""
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(f"--ray {address}: expected HOST:PORT (e.g. 10.0.0.1:6379), ray://HOST:PORT or auto")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ClusterError(f"cannot reach the Ray cluster at {address}: {exc.strerror or exc}; start one with "
                           "'ray start --head' or check RAY_ADDRESS") from None


def connect(address: str):
    """``ray.init`` for ``--ray ADDRESS``: ``auto`` is the cluster in ``RAY_ADDRESS``, or a new local
    one when it is unset; anything else must answer on its port. Returns the ray module."""
    ray = _import_ray()
    if ray.is_initialized():
        return ray
    env = os.environ.get("RAY_ADDRESS")
    target = env if address == "auto" and env else (None if address == "auto" else address)
    if target and target != "local":
        _check_reachable(target)
    try:
        ray.init(address=target, log_to_driver=False, logging_level="ERROR", include_dashboard=False,
                 configure_logging=True)
    except Exception as exc:          # noqa: BLE001 -- ray raises ConnectionError, RuntimeError, ...
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ClusterError(f"cannot connect to the Ray cluster at {target or 'a new local cluster'}: {first}") from None
    return ray


def _worker_class(ray):
    @ray.remote(max_restarts=MAX_RESTARTS, max_task_retries=MAX_TASK_RETRIES)
    class FrameWorker:
        """One process that predicts frames into ``out``; its compiled chains and model stay loaded."""

        def __init__(self, out: str, resolve: Callable, opts: dict):

            enable()
            self.out, self.resolve, self.opts = Path(out), resolve, opts

        def predict(self, pair):

            return frame_work(pair, self.out, self.resolve, self.opts)

        def pid(self) -> int:
            return os.getpid()

    return FrameWorker


def predict_batch_ray(pairs, out: Path, resolve: Callable, address: str = "auto", workers: int | None = None,
                      cpus_per_worker: int = 2, overwrite: bool = False, verify: bool = False, unmatched=None,
                      announced: str | None = None, calib=None, ply: bool = False, min_confidence: float = 0.0,
                      check_rectified: str = "warn", tile: str = "auto", disp_range=None,
                      max_depth: float | None = None, rectifier=None, frame: str = "rectified") -> dict:
    """:func:`stereojax.app.batch.predict_batch` on a Ray cluster (see the module docstring), with the
    same options and outputs.

    address: ``auto``, ``HOST:PORT`` or ``ray://HOST:PORT``. workers: how many actors (default:
    one per GPU when the cluster has GPUs, else one per ``cpus_per_worker`` CPUs). Returns the
    summary (``summary.json``), which also holds ``workers`` and ``ray`` (where they ran)."""

    out = output_folder(out)
    ray = connect(address)
    resources = ray.cluster_resources()
    gpus, cpus = int(resources.get("GPU", 0)), int(resources.get("CPU", 1))
    if workers is None:
        workers = gpus if gpus else max(1, cpus // cpus_per_worker)
    if workers < 1:
        raise ClusterError(f"--ray-workers must be at least 1, got {workers}")
    each = worker_resources(workers, gpus, cpus, cpus_per_worker)
    opts = dict(calib=calib, ply=ply, min_confidence=min_confidence, check_rectified=check_rectified, tile=tile,
                disp_range=disp_range, max_depth=max_depth)
    if rectifier is not None:
        opts.update(rectifier=rectifier, frame=frame)
    worker = _worker_class(ray)
    with folder_lock(out, "predict"):
        actors = [worker.options(**each).remote(str(out), resolve, opts) for _ in range(workers)]
        try:                  # every worker placed and started, or a clear line (never a silent wait)
            ray.get([a.pid.remote() for a in actors], timeout=PLACE_TIMEOUT_S)
        except ray.exceptions.GetTimeoutError:
            for a in actors:
                ray.kill(a)
            raise ClusterError(f"the Ray cluster did not start {workers} worker(s) with {each} each within "
                               f"{PLACE_TIMEOUT_S} s (it has {cpus} CPUs, {gpus} GPUs); use fewer --ray-workers") from None
        pool = ray.util.ActorPool(actors)

        def mapper(items):
            return pool.map_unordered(lambda actor, pair: actor.predict.remote(pair), items)

        share = f"{each['num_gpus']:g} GPU each ({gpus} GPUs)" if gpus else f"{each['num_cpus']:g} CPUs each ({cpus} CPUs)"
        where = f"Ray cluster {ray.get_runtime_context().gcs_address}: {workers} worker(s), {share}"
        try:
            summary = predict_batch_locked(pairs, out, resolve, opts, None, overwrite, verify, unmatched, announced,
                                            mapper=mapper, workers=workers, where=where)
        finally:
            for a in actors:
                ray.kill(a)
            remove_stale(out, every=True)       # the staging folder of a worker that died mid-frame
        summary.update(workers=workers, ray=where)
        write_json(out / "summary.json", summary)
    return summary
