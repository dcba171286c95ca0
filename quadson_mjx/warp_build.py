"""Builds MuJoCo Warp's kernels for a model on a pool of threads before its first step.

MJX's Warp implementation compiles its kernels (CUDA C++ through NVRTC on a GPU, LLVM on the CPU)
when a step first launches them, one module after another: for Quadson's flat model 38 modules,
60.5 s on one H100, paid by a machine's first Warp run (benchmarks/results/
time_to_policy_h100_warp_main_warp_first.log); Warp keeps them in its kernel cache
(WARP_CACHE_PATH) for the runs after it. `start` lists the modules a step of the model launches by
running MuJoCo Warp's step once with Warp's module loading replaced by a record (no kernel runs:
a launch whose module does not load is skipped), then builds them on a pool of threads while the
caller goes on (the trainer: compiling its XLA programs); the step then finds them built.

The listing sees what one step of one world launches, both branches of every conditional launch
and one pass of every device-side loop; a kernel whose launch is sized by CUDA's occupancy query
(wp.get_suggested_block_size) is built during the listing, as that query needs it. A module it
misses, or one it builds differently from the step's, is built by the step as before: slower,
never wrong. A module that fails to build here fails the same way in the step, which reports it
(Warp records the failure per module).
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import mujoco


@dataclass
class Build:
    """A running build: `modules` listed, built on `workers` threads; wait() -> seconds taken."""

    modules: int
    workers: int
    _done: threading.Event = field(default_factory=threading.Event)
    seconds: float | None = None
    errors: list[str] = field(default_factory=list)

    def wait(self, timeout: float | None = None) -> float | None:
        self._done.wait(timeout)
        return self.seconds


def warp_device(jax_device=None):
    """The Warp device that MJX's foreign calls launch on for a JAX device (default: the first
    local one): "cuda:N" for a GPU, "cpu" for the CPU."""
    import jax
    import warp as wp

    return wp.device_from_jax(jax_device if jax_device is not None else jax.local_devices()[0])


def list_modules(m: mujoco.MjModel, buffers: tuple[int, int], device) -> list[tuple[object, int]]:
    """The (Warp module, block_dim) pairs one step of MjModel m launches on Warp `device`, with the
    env's buffers (naconmax, njmax: env_model.warp_buffers) and MJX's options as env_model.put_model
    sets them. Runs MuJoCo Warp's step on one world with module loading recorded instead of done;
    not thread-safe: nothing else may launch Warp kernels meanwhile."""
    import warp as wp
    from mujoco.mjx.third_party import mujoco_warp as mjwarp
    from warp._src import context

    from quadson_mjx.env_model import quiet_overflow

    naconmax, njmax = buffers
    with wp.ScopedDevice(device):
        wm = mjwarp.put_model(m)
        wm.opt.warn_overflow = quiet_overflow(int(wm.opt.warn_overflow))
        d = mjwarp.make_data(m, nworld=1, naconmax=naconmax, njmax=njmax)
        seen: dict[tuple[int, int], tuple[object, int]] = {}
        saved = (context.Module.load, wp.capture_while, wp.capture_if, wp.get_suggested_block_size)
        loading = [False]  # inside get_suggested_block_size: the module is really built

        def record(module, device, block_dim=None, *args, **kwargs):
            if loading[0]:
                return saved[0](module, device, block_dim, *args, **kwargs)
            active = block_dim if block_dim is not None else module.options["block_dim"]
            seen.setdefault((id(module), active), (module, active))
            return None  # not loaded: wp.launch returns without launching

        def suggested_block_size(kernel, device=None):
            # CUDA's occupancy query needs the built kernel, and its answer sizes the launch that
            # follows: this module is built here, on the calling thread.
            loading[0] = True
            try:
                return saved[3](kernel, device)
            finally:
                loading[0] = False

        def each_body(*bodies, **kwargs):
            for body in bodies:
                if callable(body):
                    body(**kwargs)

        def capture_while(condition, while_body, stream=None, **kwargs):
            each_body(while_body, **kwargs)  # once: the kernels do not run, the condition stays

        def capture_if(condition, on_true=None, on_false=None, stream=None, **kwargs):
            each_body(on_true, on_false, **kwargs)

        context.Module.load, wp.capture_while, wp.capture_if = record, capture_while, capture_if
        wp.get_suggested_block_size = suggested_block_size
        try:
            mjwarp.step(wm, d)
        finally:
            context.Module.load, wp.capture_while, wp.capture_if, wp.get_suggested_block_size = saved
    return list(seen.values())


def start(m: mujoco.MjModel, buffers: tuple[int, int], device=None, workers: int | None = None) -> Build:
    """Lists the modules of a step of m (list_modules) on the calling thread, then builds them on
    `workers` threads (default: the CPU count) in the background -> the Build to wait on."""
    device = warp_device() if device is None else device
    modules = list_modules(m, buffers, device)
    workers = max(1, int(workers or os.cpu_count() or 1))
    build = Build(modules=len(modules), workers=workers)

    def load(module, block_dim):
        try:
            module.load(device, block_dim)
        except Exception as e:  # the step's own load raises it again, where it is reported
            build.errors.append(f"{module.name}: {e}")

    def run():
        t0 = time.perf_counter()
        try:
            with ThreadPoolExecutor(workers) as pool:
                for job in [pool.submit(load, mod, bd) for mod, bd in modules]:
                    job.result()
        finally:  # wait() returns whatever happened
            build.seconds = time.perf_counter() - t0
            build._done.set()

    threading.Thread(target=run, name="warp-build", daemon=True).start()
    return build
