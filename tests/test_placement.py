"""Device placement (shelljax.Placement, docs/gpu.md): the rule per stage kind, the refusals, the
[compute] table and --device; the rule on JAX's virtual CPU devices, in a fresh process."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from shelljax import InvalidInputError, Placement, StageKind
from shelljax.cli import main
from shelljax.config import bundled_data_dir, load_config

REPO = Path(__file__).resolve().parents[1]

# Two virtual CPU devices, the second standing in for the accelerator (the module's one hook,
# _accelerators, is pointed at it): XLA_FLAGS must be set before JAX starts, hence a subprocess.
_RULE_SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    import shelljax
    from shelljax import _placement, Placement, StageKind
    from shelljax._placement import current_device, to_device, to_host
    from shelljax.axisym import map_batch

    host, fake_gpu = jax.devices()
    assert (host.id, fake_gpu.id) == (0, 1)
    _placement._accelerators = lambda: [fake_gpu]
    big = _placement.SPARSE_MIN_DOFS
    where = {}
    for request in ("auto", "cpu", "gpu"):
        p = Placement(request)
        where[request] = [p.device_for(StageKind.LATENCY).id, p.device_for(StageKind.BATCHED).id,
                          p.device_for(StageKind.SPARSE, 10).id, p.device_for(StageKind.SPARSE, big).id,
                          p.sparse_on_accelerator(10), p.sparse_on_accelerator(big)]
    print("RULE", where)

    p = Placement("auto")
    with p.stage(StageKind.BATCHED) as device:
        made = jax.numpy.ones(3) * 2.0                       # created in the stage
        entry = to_device({"on_host": jax.device_put(np.arange(3.0), host), "pattern": np.arange(2)}, device)
        moved = entry["on_host"]                             # an input put on entry; NumPy stays NumPy
        summed = jax.jit(lambda x: x + made)(moved)          # computed in the stage
        # helper threads of a batch compute on the stage's device too
        threads = map_batch(lambda rows: rows + jax.numpy.zeros(1) + current_device().id, np.zeros((4, 1)), workers=2)
    back = to_host({"summed": summed, "label": "x"})
    with p.stage(StageKind.LATENCY):
        latency_made = jax.numpy.ones(2)
    print("STAGE", device.id, [list(a.devices())[0].id for a in (made, moved, summed, latency_made)],
          type(back["summed"]).__name__, back["label"], threads.ravel().tolist(), type(entry["pattern"]).__name__)
    """
)


def test_the_rule_per_stage_kind_on_virtual_devices():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    proc = subprocess.run(
        [sys.executable, "-c", _RULE_SCRIPT], check=False, capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    lines = {line.split(" ", 1)[0]: line.split(" ", 1)[1] for line in proc.stdout.splitlines() if " " in line}
    # device ids per request: latency, batched, small sparse, large sparse; then sparse_on_accelerator
    assert eval(lines["RULE"]) == {
        "auto": [0, 1, 0, 1, False, True],
        "cpu": [0, 0, 0, 0, False, False],
        "gpu": [1, 1, 1, 1, True, True],
    }
    # a batched stage's arrays (made there, put there, computed there) live on its device; a
    # latency stage's on the host; results come back as NumPy; the batch's threads ran on device 1;
    # host data (NumPy) entering a stage stays on the host
    assert lines["STAGE"] == "1 [1, 1, 1, 0] ndarray x [1.0, 1.0, 1.0, 1.0] ndarray"


def test_gpu_without_one_is_refused_naming_the_devices_and_the_extra():
    with pytest.raises(InvalidInputError, match=r"JAX sees no GPU \(devices: cpu:0 \(cpu\)\).*\.\[gpu\]"):
        Placement("gpu")
    with pytest.raises(InvalidInputError, match="'tpu' is not a device request"):
        Placement("tpu")


def test_without_an_accelerator_every_stage_runs_on_the_host():
    for request in ("auto", "cpu"):
        placement = Placement(request)
        assert {placement.device_for(kind, 10**6).platform for kind in StageKind} == {"cpu"}
        assert not placement.sparse_on_accelerator(10**6)
        assert placement.describe()["request"] == request


def _config(tmp_path: Path, compute: str) -> Path:
    path = tmp_path / "c.toml"
    path.write_text(f'[sessions]\npaths = ["bundled:sessions/pezzi.toml"]\n{compute}')
    return path


def test_the_compute_table_is_read_and_a_bad_device_named(tmp_path):
    assert load_config(_config(tmp_path, "")).device == "auto"
    assert load_config(_config(tmp_path, '[compute]\ndevice = "cpu"\n')).device == "cpu"
    with pytest.raises(InvalidInputError, match=r"c\.toml: field 'compute\.device': unknown device request 'tpu'"):
        load_config(_config(tmp_path, '[compute]\ndevice = "tpu"\n'))
    with pytest.raises(InvalidInputError, match=r"field 'compute\.threads'.*unknown key"):
        load_config(_config(tmp_path, "[compute]\nthreads = 2\n"))


def test_a_scenario_reads_the_compute_table(tmp_path):
    from shelljax.scenario import load_scenario

    text = (REPO / "configs" / "hammer.toml").read_text()
    assert load_scenario(REPO / "configs" / "hammer.toml").device == "auto"
    path = tmp_path / "hammer.toml"
    path.write_text(text + '\n[compute]\ndevice = "gpu2"\n')  # its files are bundled: it reads anywhere
    with pytest.raises(InvalidInputError, match=r"field 'compute\.device'.*unknown device request 'gpu2'"):
        load_scenario(path)


def test_device_option_is_one_line_errors(capsys):
    session = str(bundled_data_dir() / "sessions" / "pezzi.toml")
    assert main(["estimate", session, "--method", "closed-form", "--device", "gpu"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "JAX sees no GPU" in err and ".[gpu]" in err
    assert main(["estimate", session, "--device", "tpu"]) == 2
    assert "--device: invalid choice: 'tpu'" in capsys.readouterr().err
    assert main(["estimate", session, "--method", "closed-form", "--device", "auto", "--json"]) == 0
    assert '"gauge_pressure"' in capsys.readouterr().out


def _fresh_python(script: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    env.pop("JAX_PLATFORMS", None)
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)], check=False, capture_output=True, text=True, env=env
    )


def test_importing_shelljax_starts_no_backend_so_device_cpu_is_in_time():
    # jax_platforms is read when JAX first starts a backend: a platform this machine lacks, set
    # after every import, must then fail the first computation, which shows none had started
    proc = _fresh_python(
        """
        import jax
        import shelljax, shelljax.cli, shelljax.runner, shelljax.scenario, shelljax.estimate
        import shelljax.axisym, shelljax.shell3d, shelljax.dynamics, shelljax.diagnose, shelljax.rig
        jax.config.update("jax_platforms", "tpu")
        try:
            jax.devices()
        except RuntimeError:
            print("NOT STARTED")
        """
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "NOT STARTED"
    # and --device cpu, in a fresh process, restricts JAX to its CPU before it starts
    proc = _fresh_python(
        f"""
        import jax
        from shelljax.cli import main
        assert main(["estimate", {str(bundled_data_dir() / "sessions" / "pezzi.toml")!r}, "--method", "closed-form",
                     "--device", "cpu", "--json"]) == 0
        print("PLATFORMS", jax.config.jax_platforms, [d.platform for d in jax.devices()])
        """
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "PLATFORMS cpu ['cpu']"


def test_a_sparse_stage_on_an_accelerator_takes_the_krylov_newton(monkeypatch):
    """The scenario's Newton follows its stage's device: the host factorisation on the CPU, the
    device-side CG on a GPU (a stand-in device object: no GPU here)."""
    from types import SimpleNamespace

    from shelljax import dynamics as d
    from shelljax.scenario import _run

    scenario = SimpleNamespace(step_tolerance=1e-9)
    assert type(_run._minimiser(scenario)) is d.SparseNewton
    monkeypatch.setattr(_run, "current_device", lambda: SimpleNamespace(platform="gpu"))
    chosen = _run._minimiser(scenario)
    assert type(chosen) is d.KrylovNewton and chosen.step_tolerance == 1e-9
