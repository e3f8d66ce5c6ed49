"""What `eskin train`'s searched default costs against the fixed default it replaced, in one run.

Both train on the same SIMULATED campaign (``eskin.simulate``, ``--participants`` people, both
runs: 840 recordings for 70, the campaign of the default `eskin simulate`), one after the other in
this process, single-threaded (BLAS and the core), alternating when ``--repeats`` > 1:

- fixed: the recipe `eskin train` used before the search (tensor-SVM, D = 100, Algorithm 2
  subsampling, every negative; each one-vs-all machine selects its own setting of the paper's
  grid times the amplitude widths off/1/4 by 10 participant-grouped splits);
- searched: `eskin train`'s default now (``eskin.train_model`` with no recipe option):
  successive halving over 24 recipes x the same grid (eskin.learn.recipes).

Printed: CPU seconds of each (process time: the machine is shared, wall time is not the
point), their ratio, the recipe each chose with its inner-CV figure, and the heap one host
``StreamClassifier`` of each exported model holds (``bench_stream_memory.per_stream``: glibc's
heap in use around the construction of ``--streams`` streams of the loaded model).

    python benchmarks/bench_recipe_search.py [--participants 70] [--repeats 1]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("ESKIN_NUM_THREADS", "1")

import eskin  # noqa: E402
from eskin.deploy.export import CompiledModel, export_model  # noqa: E402
from eskin.learn.training import train_model  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_stream_memory import per_stream  # noqa: E402

FIXED = {"machine": "svm", "D": 100, "subsample": "algorithm2", "negatives": "all"}


def campaign(cache: Path, participants: int) -> Path:
    path = cache / f"bench_recipe_{participants}p.h5"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        eskin.simulate(path, participants=participants, seed=3, overwrite=True)
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--participants", type=int, default=70)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_bench_recipe"))
    ap.add_argument("--streams", type=int, default=5, help="streams built per model (heap)")
    args = ap.parse_args(argv)
    path = campaign(args.cache, args.participants)
    cpu = {"fixed": [], "searched": []}
    models = {}
    for _ in range(args.repeats):
        for name, options in (("fixed", FIXED), ("searched", {})):
            t0 = time.process_time()
            models[name] = train_model(path, n_jobs=1, **options)
            cpu[name].append(time.process_time() - t0)
    n = len(eskin.load_campaign(path))
    print(f"SIMULATED campaign {path.name} ({n} recordings), CPU seconds, least of "
          f"{args.repeats}:")
    fixed, searched = min(cpu["fixed"]), min(cpu["searched"])
    m = models["fixed"]
    errs = ", ".join(f"{s['class']} {100 * s['selection_terms']['mean_test_error']:.1f} %"
                     for s in m.selected)
    print(f"  fixed default (svm D=100 algorithm2 all, per-machine CV): {fixed:8.1f} s "
          f"(binary inner-CV errors: {errs})")
    rs = models["searched"].training["recipe_search"]
    c = rs["chosen"]
    print(f"  searched default ({rs['evaluations']} candidate-split scores):  {searched:8.1f} s "
          f"(chose {c['machine']} D={c['D']} {c['subsample']} negatives={c['negatives']}, "
          f"multi-class inner-CV error {100 * c['cv_error']:.1f} %)")
    print(f"  ratio searched / fixed: {searched / fixed:.2f}")
    print(f"host StreamClassifier heap (mean of {args.streams} streams of the exported model):")
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("fixed", "searched"):
            data = Path(export_model(models[name], Path(tmp) / f"{name}.eskin")).read_bytes()
            cm = CompiledModel(data)
            model_heap, stream_heap = per_stream(data, args.streams)
            print(f"  {name:8s}: one stream {stream_heap / 1024:.1f} KB ({stream_heap} B); "
                  f"model {len(data)} B, {cm.n_support} support vectors, D={cm.D}, loaded "
                  f"{model_heap / 1024:.0f} KB (shared by the streams)")


if __name__ == "__main__":
    main()
