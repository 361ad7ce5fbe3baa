"""Export the default experiment's traced programs into the package (``shelljax/data/programs/``).

A fit's or posterior's program is kept across processes by its key (package sources, jax and jaxlib versions, the
arguments' structure; ``shelljax/_programs.py``). Shipping the one ``shelljax run
configs/paper.toml`` uses lets a new user's first fit skip its tracing: only XLA compiles.
Any change to the package's sources changes the key, so run this after every such change
(``tests/test_estimate_programs.py`` fails until you do)::

    python tools/ship_programs.py [--config configs/paper.toml]

It fits every calibration and estimation session of the config and, where the config runs
bayes, samples the posterior of its estimation sessions (one program serves all of a structure),
then replaces the shipped programs with the ones those runs exported.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "paper.toml"))
    args = parser.parse_args()
    cache = Path(tempfile.mkdtemp(prefix="shelljax-ship-"))
    os.environ["SHELLJAX_CACHE_DIR"] = str(cache)  # before shelljax sets JAX's cache directory
    os.environ.pop("SHELLJAX_NO_COMPILATION_CACHE", None)

    import shelljax
    from shelljax.config import load_config
    from shelljax.estimate import run_estimator
    from shelljax.session import load_session

    shipped = Path(shelljax.__file__).resolve().parent / "data" / "programs"
    if shipped.parent.parent != ROOT / "shelljax":
        raise SystemExit(f"shelljax is imported from {shipped.parent.parent}, not this checkout: pip install -e {ROOT}")
    config = load_config(args.config)
    options = config.estimator_options
    # the shipped programs move aside while the fits run: a fit that finds its program there
    # (sources unchanged) would export nothing
    previous = Path(tempfile.mkdtemp(prefix="shelljax-shipped-")) / "programs"
    if shipped.is_dir():
        shutil.move(shipped, previous)
    shipped.mkdir(parents=True)
    try:
        for path in (*config.calibration_sessions, *config.sessions):
            session = load_session(path)
            fit = run_estimator("fit", session, options)
            if "bayes" in config.methods and path in config.sessions:
                run_estimator("bayes", session, options, fit=fit, progress=False)
            print(f"fitted {path.name}", flush=True)
        exported = sorted((cache / "programs").glob("*.jaxexport"))
        if not exported:
            raise SystemExit(f"the fits of {args.config} exported no program; the shipped ones are left as they were")
        for path in exported:
            shutil.copyfile(path, shipped / path.name)
            print(f"shipped {path.name} ({path.stat().st_size / 1e3:.0f} kB)")
    except BaseException:
        shutil.rmtree(shipped, ignore_errors=True)
        if previous.is_dir():
            shutil.move(previous, shipped)
        raise
    finally:
        shutil.rmtree(cache, ignore_errors=True)
        shutil.rmtree(previous.parent, ignore_errors=True)


if __name__ == "__main__":
    main()
