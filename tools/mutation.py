#!/usr/bin/env python3
"""Mutation testing of the modules that guard data and results (`make mutation`, docs/testing.md).

A mutant is one small change to a module (a comparison turned around, a constant moved by one, a
return value flipped, a check deleted); the tests that cover the module either fail on it (the
mutant is *killed*) or pass (it *survives*: a missing test, or a change that alters nothing).

* Python modules: cosmic-ray (PyPI) generates the mutants of the operator families below;
  tools/mutant_runner.py runs the module's test files on each, in copies of the tree under
  build/mutation (the work tree is never changed), one per core (--jobs): first the tests that
  execute the mutated line (from one run under coverage.py), then, if none fails, all of them.
* C++ files (the model loader in cpp/src/model_format.cpp, the frame decoder in
  cpp/src/protocol.cpp): this script's own mutator, on the lines between two markers, in a copy
  of the sources built once (Debug, no optimisation: fast rebuilds); each mutant recompiles one
  file, relinks the GoogleTest binary that covers it and runs it. A mutant that does not compile
  is not a mutant (not counted).

Every module's mutants are all generated; with --sample N (the default of `make mutation`) a
random N of them run, drawn with the seed the run prints first (``MUTATION: seed=<n>``: a fresh
one on each run unless --seed gives it, so that no test suite is tuned to one sample; the same
seed and the same source give the same sample again). --sample all runs every mutant. --diff REV
keeps only the mutants on the lines that differ between REV and the work tree (``git diff
-U0``: `make mutation-diff`). Output, one line per module:

    MUTATION: module=<path> mutants=<n> killed=<k> score=<k/n> ci95=[lo, hi] generated=<g>
    equivalent=<e>

(ci95: the Wilson score interval of the module's kill rate, from the mutants that ran;
equivalent: the mutants of EQUIVALENT, shown to change no behaviour, which are never drawn) and
build/mutation/survivors.txt lists each survivor (file, line, operator, the changed text).
Timeouts (a mutant that makes the tests hang, 3x the unmutated run plus 30 s) count as killed.
Runs under `nice -n 10`; the exit status is 1 if a module is below --threshold.
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import os
import random
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "build" / "mutation"

#: module -> the pytest arguments of the tests that cover it
PYTHON_MODULES: dict[str, list[str]] = {
    "python/eskin/data/journal.py": [
        "tests/python/data/test_journal.py", "tests/python/data/test_journal_failures.py",
        "tests/python/data/test_campaign_recovery.py",
        # the operating system's calls failing in turn, in-process (the command-line half of
        # the file, on mounted file systems, is left to `make test`)
        "tests/python/data/test_io_errors.py::test_the_writer_loses_nothing_that_returned_when_a_call_fails",
        "tests/python/data/test_io_errors.py::test_recovery_keeps_the_journal_until_the_campaign_is_in_place"],
    "python/eskin/data/campaign.py": [
        "tests/python/data/test_campaign.py", "tests/python/data/test_limits.py",
        "tests/python/data/test_campaign_storage.py", "tests/python/data/test_campaign_patches.py",
        "tests/python/data/test_campaign_encoder.py", "tests/python/data/test_campaign_labels.py",
        "tests/python/data/test_campaign_attrs.py", "tests/python/data/test_campaign_memory.py",
        "tests/python/data/test_campaign_writer.py",
        # the campaign built from a journal: recovery's checks and placing the file
        "tests/python/data/test_campaign_recovery.py", "tests/python/data/test_recover_checks.py",
        "tests/python/data/test_campaign_recover.py",
        "tests/python/data/test_io_errors.py::test_the_writer_loses_nothing_that_returned_when_a_call_fails",
        "tests/python/data/test_io_errors.py::test_recovery_keeps_the_journal_until_the_campaign_is_in_place"],
    "python/eskin/learn/evaluation.py": [
        # its scores, folds, bootstrap and a small evaluation end to end (seconds); the tests of
        # the command on a simulated campaign and on Dask clusters are left to `make test`
        "tests/python/learn/test_evaluation.py", "-k",
        "not dask and not cluster and not scheduler and not simulated_campaign "
        "and not unknown_group_label"],
    "python/eskin/link/protocol.py": ["tests/python/link/test_protocol.py"],
    "python/eskin/deploy/export.py": [
        # all but the two that train on a campaign first (90 s of the 2 min)
        "tests/python/deploy/test_export.py", "tests/python/deploy/test_export_limits.py",
        "tests/python/deploy/test_export_calibration.py", "tests/python/deploy/test_amplitude.py",
        "-k",
        "not train_export_classify_matches and not cli_export_writes_model_and_header"],
    # the recipe `eskin train` chooses and what fits a controller's budget
    "python/eskin/learn/recipes.py": ["tests/python/learn/test_recipes.py"],
    "python/eskin/deploy/target.py": ["tests/python/deploy/test_target.py"],
    # the replay file eskin-fw-sim streams: writer and reader
    "python/eskin/data/replay.py": [
        "tests/python/data/test_replay.py", "tests/python/data/test_replay_limits.py"],
    # bytes -> checked frames -> events and the link's counters (the two tests of
    # test_accounting.py that stream through eskin-fw-sim, 20 s each, are left to `make test`)
    "python/eskin/link/receiver.py": [
        "tests/python/link/test_listener.py", "tests/python/link/test_frame_checks.py",
        "tests/python/link/test_receiver_finish.py", "tests/python/link/test_receiver_counts.py",
        "tests/python/link/test_accounting.py::test_lost_samples_reconcile_with_the_controller_count"],
    # the calibrated decision rule of a model: fitted here, written by the exporter
    "python/eskin/learn/calibration.py": [
        "tests/python/learn/test_calibration.py", "tests/python/learn/test_calibration_folds.py",
        "tests/python/learn/test_calibration_edges.py",
        "tests/python/deploy/test_export_calibration.py"],
}

#: test files named after a module (tests/python/<layer>/test_<name>*.py) that its list leaves
#: out, with the reason (tests/python/test_mutation_map.py checks the rest are listed)
NOT_LISTED: dict[str, str] = {}

#: cosmic-ray operator families run (the others, e.g. swapping + for <<, make mostly mutants
#: that crash at once or duplicate these)
PYTHON_OPERATORS = re.compile(
    r"core/(ReplaceComparisonOperator_.*|NumberReplacer|ReplaceTrueWithFalse|ReplaceFalseWithTrue"
    r"|ReplaceAndWithOr|ReplaceOrWithAnd|AddNot|ReplaceUnaryOperator_Delete_Not"
    r"|ZeroIterationForLoop|ReplaceBreakWithContinue|ReplaceContinueWithBreak"
    r"|ReplaceBinaryOperator_(Add_Sub|Sub_Add|Mul_Div|Div_Mul|FloorDiv_Mul|Mod_FloorDiv"
    r"|BitOr_BitAnd|BitAnd_BitOr))$")


@dataclass(frozen=True)
class CppModule:
    path: str
    start: str  # the mutated region: from the line holding `start`
    end: str | None  # ... to the line before the one holding `end` (None: end of file)
    targets: tuple[str, ...]  # the GoogleTest executables that cover it (tests/cpp/<target>.cpp)


CPP_MODULES = [
    CppModule("cpp/src/model_format.cpp", "class Reader {", "Model Model::from_bytes",
              ("test_model",)),
    CppModule("cpp/src/protocol.cpp", "std::ptrdiff_t cobs_decode(", None, ("test_protocol",)),
    # the decision path of a loaded model: tables, machines, the calibrated rule, the stream
    CppModule("cpp/src/model.cpp", "inline bool spans(", None, ("test_model",)),
    # the controller's arithmetic: the input's bases and the tiled overlap
    CppModule("cpp/src/scalar_bases.hpp", "int one_sided_jacobi(", None, ("test_scalar_bases",)),
    CppModule("cpp/src/model_overlap.cpp", "template <int KB, int LB>", "#if defined(ESKIN_DEVICE)",
              ("test_model_overlap",)),
]


@dataclass(frozen=True)
class Equivalent:
    """A mutant shown to change no behaviour: the mutated line (``line`` as the module has it,
    ``mutant`` as the mutant has it, both stripped) and the operator that makes it."""
    operator: str  # cosmic-ray's operator name, or this script's (swap<=<, constant+1, ...)
    line: str
    mutant: str
    why: str


#: The known-equivalent mutants of each module, each with the reason no test can observe it
#: (docs/testing.md, "Equivalent mutants"): generated and counted (``equivalent=<e>``) but never
#: drawn, so that a score counts only mutants a test could kill. A mutant is named by its text,
#: not its position: an edit of its line makes the entry stale, which
#: tests/python/test_mutation_map.py catches (every entry must name exactly one mutant).
#: Only a mutant whose every observable output (returned values, statuses, flags, messages, to
#: the bit) is the same may be listed; a surviving mutant that a test could kill is a missing
#: test, never an entry.
_PROJ = "g.proj[zz] = kProjectionCache && N <= 64 && N < a * a;"
_ROUTE = ("another route to the same distance: the cached projections' inner product "
          "<P_sv, P_x>_F instead of the overlap of the bases, equal to rounding (1e-15); "
          "only the tables' RAM differs")
_XR = "int xr[3] = {0, 0, 0};"
_XR_WHY = ("the input's ranks: every one written by the basis computation before any read "
           "(a failed computation returns first)")
_TARGETS = "targets = ((y == 1)[:, None] if binary else"
_PATCH = 'if column.shape != (n,) or column.dtype.kind != "u":'
_EXIT = 'elif self._n == 0 or self.on_error == "discard":'
_HEAD = ("if len(head) < len(HEADER_MAGIC) + 4 or head[: len(HEADER_MAGIC)] != "
         "HEADER_MAGIC:")
_HEAD_WHY = "the head is a read of the magic and the size, 12 bytes: never more (12 is one object)"
_TEXT = "if len(text) < n or len(crc) < 4 or _CRC.unpack(crc)[0] != zlib.crc32(text):"
_TEXT_WHY = ("the text is a read of n bytes, never more; fewer means the file ended, and then the "
             "CRC's read is short too and refused by the next test")
_RHEAD_WHY = "a record's head is a read of its 20 bytes: never more (20 is one object)"
_READS = ("which of two read paths takes a run of recordings: one slice of the file or one read "
          "per recording (sorted unique rows either way: a difference of 1 is the least there is), "
          "the same rows")
_CAL = "index, conf, _ = calibrated_decision(F, slopes, offsets, 0.0, binary)"
_BIN = "z = a[0] * F[:, 0] + b[0]"
_ONE = ("a binary calibration has exactly one machine (checked above): index -1 is index 0 "
        "of its one slope, offset and column of values")
_WS = ("a workspace's initial fill at construction: every entry a computation reads is written "
       "by that computation first (compute() scales the pattern into x_, each mode fills its QR "
       "columns, factor, reflectors, squared singular values, order and column before reading "
       "them, one_sided_jacobi sets w and each sweep's norms)")
_WS_LINES = (
    "x_.assign(layout_.tensor_size(), Real(0));",
    "qr_.assign(layout_.tensor_size(), Real(0));  // the thin side of an unfolding, then its QR",
    "b_.assign(q * q, Real(0));",
    "w_.assign(q * q, Real(0));",
    "tau_.assign(q, Real(0));",
    "diag_.assign(q, Real(0));",
    "sv_.assign(q, Real(0));",
    "norms_.assign(q, Real(0));",
    "col_.assign(n, Real(0));",
)
_FULL_RANK = ("a mode's alpha is at most q = min(m, N) (the stored alphas are within it): "
              "alpha >= N only when alpha = N <= m, so m > N and m != N, alpha >= N and "
              "alpha == N agree (and `is` on such small integers is ==)")
_S = 'const bool converted = name.size() > 2 && (name.compare(name.size() - 2, 2, "_s") == 0 ||'
_HZ = 'name.compare(name.size() - 3, 3, "_hz") == 0);'
_SUFFIX = ("which window fields count as seconds or hertz, by the end of the name: "
           "std::string::compare(pos, len, s) takes at most size - pos characters, so a length "
           "one past the end compares the same suffix; and every name reaching the test is one "
           "of the known fields (an unknown one is refused just before), none of them 3 "
           "characters or fewer")
_JAC = ("if (!(std::fabs(g) > eps * std::sqrt(a * c)) || !(std::fabs(g) > tiny)) continue;")
_ZERO = ("if (amax == Real(0)) return fail(bases, ranks, KernelStatus::ok);  "
         "// rank 0 everywhere")
_PROOF = ("return std::isfinite(t2) && r2 * t2 * Real(4096) * rank_tolerance<Real>() < "
          "Real(1);")

EQUIVALENT: dict[str, list[Equivalent]] = {
    "cpp/src/model.cpp": [
        Equivalent("swap<<=", _PROJ, _PROJ.replace("N < a", "N <= a"), _ROUTE),
        Equivalent("swap<=<", _PROJ, _PROJ.replace("N <= 64", "N < 64"), _ROUTE),
        Equivalent("constant+1", _PROJ, _PROJ.replace("64", "65"), _ROUTE),
        Equivalent("swap&&||", _PROJ, _PROJ.replace("kProjectionCache &&", "kProjectionCache ||"),
                   _ROUTE),
        Equivalent("swap&&||", _PROJ, _PROJ.replace("N <= 64 &&", "N <= 64 ||"), _ROUTE),
        Equivalent("constant+1", "for (int z = 0; z < 3; ++z) {",
                   "for (int z = 1; z < 3; ++z) {",
                   "the projection route's choice skipping the row mode, which then takes the "
                   "overlap route: " + _ROUTE),
        Equivalent("swap&&||", "wide = kWideTables && m.is_float64();",
                   "wide = kWideTables || m.is_float64();",
                   "a float32 model's distance tables in double on the host: the same distances "
                   "to float rounding (the decisions are compared with the hand computation at "
                   "1e-4 in float32)"),
        *(Equivalent(op, "if (!proj && !f64 && a < N) {", mutant,
                     "the host's batched float32 overlaps (OverlapsF32) or the one-by-one route "
                     "the controller takes: the same distances to float rounding; at a = N the "
                     "one-by-one route's spans() gives |ri - rx|, which the batched sum gives "
                     "to rounding")
          for op, mutant in (("swap<<=", "if (!proj && !f64 && a <= N) {"),
                             ("delete check", "if (false && (!proj && !f64 && a < N)) {"))),
        Equivalent("delete check", "if (ks != KernelStatus::ok) return ClassifyStatus::kKernel;",
                   "if (false && (ks != KernelStatus::ok)) return ClassifyStatus::kKernel;",
                   "the basis computation's other failures cannot happen here: bad_argument "
                   "(its pointers are the classifier's own buffers) and no_convergence (the "
                   "Jacobi sweeps' cap is never reached)"),
        Equivalent("constant+1", "for (std::int64_t t = 0; t < length; ++t)",
                   "for (std::int64_t t = 1; t < length; ++t)",
                   "a NaN at a taxel's sample 0 then reaches the tensor: both subsampling "
                   "methods (Algorithm 2's first index and the even spread's) and the "
                   "interpolation of a short window read sample 0, and the basis computation "
                   "reports it not finite: the same kNotFinite"),
        Equivalent("delete check", "if (spans(ri, rx, N)) {",
                   "if (false && (spans(ri, rx, N))) {",
                   "another route to the same distance: when one subspace is all of R^N the "
                   "general sum r1 + r2 - 2 ov gives |r1 - r2| to rounding (1e-15)"),
        Equivalent("constant+1", "ws(layout, 1),  // one pattern per decision: no batch of "
                   "scaled copies", "ws(layout, 2),  // one pattern per decision: no batch of "
                   "scaled copies", "a workspace for two patterns where one is used"),
        Equivalent("constant+1",
                   "tensor(raw ? static_cast<std::size_t>(m.rows()) * m.cols() * m.D() : 0),",
                   "tensor(raw ? static_cast<std::size_t>(m.rows()) * m.cols() * m.D() : 1),",
                   "the raw tensor of the private tensors-only classifier (a StreamClassifier's), "
                   "which never classifies a raw recording: never used"),
        Equivalent("constant+1",
                   "static_cast<std::int64_t>(raw ? kMaxTouches : 1)),",
                   "static_cast<std::int64_t>(raw ? kMaxTouches : 2)),",
                   "the touches the tensors-only classifier's window choice holds: it never "
                   "chooses a window"),
        Equivalent("constant+1", "std::size_t n_proj = 0;", "std::size_t n_proj = 1;",
                   "the input's projection buffer: one entry where none is used"),
        Equivalent("constant+1",
                   "const std::size_t n_dist = t.groups.size() * static_cast<std::size_t>("
                   "m.n_support()) * 3;",
                   "const std::size_t n_dist = t.groups.size() * static_cast<std::size_t>("
                   "m.n_support()) * 4;",
                   "the distance table sized for four modes where three are written and read"),
        Equivalent("constant+1",
                   "const std::size_t n_gap = m.has_amplitude() ? static_cast<std::size_t>("
                   "m.n_support()) : 0;",
                   "const std::size_t n_gap = m.has_amplitude() ? static_cast<std::size_t>("
                   "m.n_support()) : 1;",
                   "a gap buffer of one entry in a model without the amplitude factor, which "
                   "never reads it"),
        Equivalent("constant+1", _XR, "int xr[4] = {0, 0, 0};", _XR_WHY),
        Equivalent("constant+1", _XR, "int xr[3] = {1, 0, 0};", _XR_WHY),
        Equivalent("constant+1", _XR, "int xr[3] = {0, 1, 0};", _XR_WHY),
        Equivalent("constant+1", _XR, "int xr[3] = {0, 0, 1};", _XR_WHY),
        Equivalent("constant+1", "DecisionReal w[3];", "DecisionReal w[4];",
                   "the kernel widths' array one longer than the three written and read"),
        Equivalent("constant+1", "int claims = 0, claimed = -1;",
                   "int claims = 0, claimed = -2;",
                   "read only when exactly one machine claimed, which sets it"),
    ],
    "cpp/src/scalar_bases.hpp": [
        *(Equivalent("constant+1", ln, ln.replace("Real(0)", "Real(1)"), _WS) for ln in _WS_LINES),
        Equivalent("return true", "if (!(diag_[c] != Real(0))) return false;",
                   "if (!(diag_[c] != Real(0))) return true;",
                   "the quick proof's early refusal of a zero diagonal: without it, R^-1's entry "
                   "1 / 0 is infinite, so t2 is, and the isfinite(t2) of the result refuses all "
                   "the same"),
        Equivalent("swap>>=", "while (r < q && smax > 0 && sv_[order_[r]] > tau * smax) ++r;",
                   "while (r < q && smax >= 0 && sv_[order_[r]] > tau * smax) ++r;",
                   "the squared singular values are >= 0: at smax = 0 every one is 0, and "
                   "0 > tau * 0 is false, so the rank is 0 either way (NaN fails both)"),
        Equivalent("constant+1", "for (std::size_t i = 0; i < n * n; ++i) w[i] = Real(0);",
                   "for (std::size_t i = 1; i < n * n; ++i) w[i] = Real(0);",
                   "w[0] is the identity's first entry, set to 1 by the next loop"),
        *(Equivalent(op, "for (int sweep = 0; sweep < 60; ++sweep) {", mutant,
                     "the cap of 60 sweeps is never reached: cyclic Jacobi converges "
                     "quadratically (the tests' worst is 9 sweeps, 20 random 16 x 16 in float), "
                     "so 61 are never needed either")
          for op, mutant in (("swap<<=", "for (int sweep = 0; sweep <= 60; ++sweep) {"),
                             ("constant+1", "for (int sweep = 0; sweep < 61; ++sweep) {"))),
        *(Equivalent("swap>>=", _JAC, mutant,
                     "differs only where |g| equals its rounding-level threshold to the last bit: "
                     "a pair orthogonal to within rounding, rotated or not")
          for mutant in (_JAC.replace("> eps", ">= eps"), _JAC.replace("> tiny", ">= tiny"))),
        Equivalent("constant+1", "return -1;", "return -2;",
                   "non-convergence, never reached (see the cap of 60 sweeps); its one caller "
                   "tests < 0"),
        *(Equivalent("constant+1", "std::size_t q = 1, n = 1;", mutant,
                     "the start of the largest q and n over the modes, each at least 1: starting "
                     "at 2 only makes a workspace one larger where every mode has 1")
          for mutant in ("std::size_t q = 2, n = 1;", "std::size_t q = 1, n = 2;")),
        Equivalent("delete check", _ZERO, f"if (false && (amax == Real(0))) {_ZERO[21:]}",
                   "a zero pattern then goes on with 0 * (1 / 0) = NaN entries: every squared "
                   "singular value is NaN, no comparison with it holds, the rank is 0 and the "
                   "bases the zeros written beyond the rank, with status ok: the same outputs"),
        Equivalent("constant+1", "const Real inv = Real(1) / amax;",
                   "const Real inv = Real(2) / amax;",
                   "a power of two: the scaled pattern is exactly twice the other and every "
                   "step after it is scale-free (relative thresholds, unit vectors): the same "
                   "bases bit for bit (ScalarBases.APatternsBasesDoNotDependOnItsScale...)"),
        Equivalent("constant+1", "tau_[c] = 0;", "tau_[c] = 1;",
                   "the reflector of a zero column: X[c.., c] is zero, so applying it with any "
                   "tau changes nothing"),
        Equivalent("swap>>=", "const Real a = col[c] > 0 ? -nrm : nrm;",
                   "const Real a = col[c] >= 0 ? -nrm : nrm;",
                   "at a diagonal entry of exactly 0 both reflectors are exact and mirror each "
                   "other (v' = D v, D flipping that entry's sign), so R changes by signs only "
                   "and the bases' sign rule makes them equal"),
        Equivalent("swap>>=", "if (m > n && alpha >= n && spans_all(n, X, L)) {",
                   "if (m >= n && alpha >= n && spans_all(n, X, L)) {",
                   "a square unfolding of full rank then gets the identity basis instead of its "
                   "singular vectors: the same subspace (all of R^n) and rank, and a pattern's "
                   "bases are only ever used as subspaces (the kernel's V_a^T V_b)"),
        Equivalent("constant+1", "std::fill(out + n * n, out + alpha * n, Out(0));",
                   "std::fill(out + n * n, out + alpha * n, Out(1));",
                   "here alpha >= n and alpha <= Q = n (m > n): the range is empty"),
        *(Equivalent(op, "if (one_sided_jacobi(q, B, W, norms_.data()) < 0) return false;", mutant,
                     "one_sided_jacobi returns at least 1 when it converges and -1 when it does "
                     "not, which no input reaches (see the cap of 60 sweeps)")
          for op, mutant in (
              ("swap<<=", "if (one_sided_jacobi(q, B, W, norms_.data()) <= 0) return false;"),
              ("constant+1", "if (one_sided_jacobi(q, B, W, norms_.data()) < 1) return false;"),
              ("return true", "if (one_sided_jacobi(q, B, W, norms_.data()) < 0) return true;"))),
        Equivalent("swap<<=", "const Real sign = col[big] < 0 ? Real(-1) : Real(1);",
                   "const Real sign = col[big] <= 0 ? Real(-1) : Real(1);",
                   "col[big] is 0 only for a zero column, and the columns within the rank are "
                   "unit vectors"),
        Equivalent("delete check", "if (!(diag_[c] != Real(0))) return false;",
                   "if (false && (!(diag_[c] != Real(0)))) return false;",
                   "as its return true above: 1 / 0 makes t2 infinite, which isfinite refuses"),
        Equivalent("swap<<=", _PROOF, _PROOF.replace("< Real(1)", "<= Real(1)"),
                   "differs only for a product equal to the bound to the last bit"),
        Equivalent("constant+1", "std::size_t r = 0;", "std::size_t r = 1;",
                   "a pattern that is not all zero (which returns before) has a largest squared "
                   "singular value above 0 in every mode (each unfolding holds all its entries), "
                   "and that one is always counted"),
        Equivalent("swap>>=", "while (r < q && smax > 0 && sv_[order_[r]] > tau * smax) ++r;",
                   "while (r < q && smax > 0 && sv_[order_[r]] >= tau * smax) ++r;",
                   "differs only for a squared singular value equal to the tolerance to the "
                   "last bit"),
        Equivalent("constant+1", "order_.assign(q, 0);", "order_.assign(q, 1);", _WS),
        Equivalent("swap<<=", "for (std::size_t j = 0; j + 1 < n; ++j)",
                   "for (std::size_t j = 0; j + 1 <= n; ++j)",
                   "one_sided_jacobi's pairs (j, k > j): the one more j, n - 1, has no k "
                   "(k runs from j + 1 = n below n), so nothing more is read or rotated"),
    ],
    "cpp/src/model_format.cpp": [
        *(Equivalent(op, "if (p == nullptr) return false;", mutant,
                     "the bases' read never fails: read_svbs_shape has refused a section too "
                     "short for the ranks and every mode's bases (n_sv * bytes_needed + "
                     "rank_bytes > remaining) before any is read, so the branch is never taken")
          for op, mutant in (("return true", "if (p == nullptr) return true;"),
                             ("delete check", "if (false && (p == nullptr)) return false;"))),
        *(Equivalent("constant+1", _S, mutant, _SUFFIX)
          for mutant in (_S.replace("> 2", "> 3"), _S.replace(", 2, ", ", 3, "))),
        Equivalent("constant+1", _HZ, _HZ.replace(", 3, ", ", 4, "), _SUFFIX),
        *(Equivalent("constant+1", f"std::uint{w}_t {v} = 0;", f"std::uint{w}_t {v} = 1;",
                     f"the start of a {w}-bit little-endian read: each of its {w // 8} steps "
                     f"shifts {v} left by 8 bits, so the start's bits are all shifted out before "
                     f"{v} is used") for w in (32, 64) for v in "vu"),
        Equivalent("constant+1", "for (auto i : mm.sv_index) used[i] = 1;",
                   "for (auto i : mm.sv_index) used[i] = 2;",
                   "a support vector's mark of use: only tested for zero (!used[i])"),
        Equivalent("return true", "if (!u32(field, u)) return false;",
                   "if (!u32(field, u)) return true;",
                   "a 4-byte field that runs past its section, taken as read: the error is "
                   "already set and sticky, so the parser's next read of the section (the next "
                   "field of the machine, or the padding after its coefficients) fails and it "
                   "returns false with that first message; the value read is never kept"),
        Equivalent("return true",
                   'if (!r.u32("n_modes", Z) || !r.u32("n_sv", n_sv)) return false;',
                   'if (!r.u32("n_modes", Z) || !r.u32("n_sv", n_sv)) return true;',
                   "SVBS too short for its two counts, taken as read: the reader's error is "
                   "already set and sticky, and Z (0, or a count read) fails the next check or "
                   "the next read fails: the parser returns false with that first message"),
        Equivalent("return true", "if (!need(model_format::kNameBytes, field)) return false;",
                   "if (!need(model_format::kNameBytes, field)) return true;",
                   "a name that runs past its section, taken as read (and left empty): a class "
                   "name never does (parse_clas needs all of them first), and a window field's "
                   "name is followed at once by its value, whose read fails on the sticky error: "
                   "the same first message"),
        Equivalent("return true",
                   'if (!r.u32("n_machines", n) || !r.zero_u32("reserved")) return false;',
                   'if (!r.u32("n_machines", n) || !r.zero_u32("reserved")) return true;',
                   "MACH's count unread or its reserved word non-zero, the section taken as "
                   "parsed with no machine: the error is set and sticky, so the next section's "
                   "first read fails, or (MACH the last) check_machines refuses a model without "
                   "machines: false with the first message either way"),
    ],
    "cpp/src/protocol.cpp": [
        Equivalent("delete check", "if (!is_known_type(type)) return false;",
                   "if (false && (!is_known_type(type))) return false;",
                   "an unknown type then reaches fixed_payload_size, which has no case for it "
                   "and gives -1: the frame is refused (malformed) all the same"),
        Equivalent("swap<<=", "max_frame_size_(max_frame_size < kHeaderSize + kCrcSize",
                   "max_frame_size_(max_frame_size <= kHeaderSize + kCrcSize",
                   "a maximum of exactly header plus CRC is clamped to itself either way (the "
                   "capacity is at least that: static_assert of every decoder)"),
        Equivalent("delete check", "if (code == 0) return -1;",
                   "if (false && (code == 0)) return -1;",
                   "a zero code makes the run (code - 1) wrap to SIZE_MAX, which the next "
                   "check refuses with the same -1"),
        Equivalent("swap>>=", ": (max_frame_size > capacity ? capacity : max_frame_size)),",
                   ": (max_frame_size >= capacity ? capacity : max_frame_size)),",
                   "at equality both branches give the same value"),
        *(Equivalent(op, "if (len < 0) {", mutant,
                     "a block that decodes to 0 bytes is then counted malformed here instead of "
                     "by the next check (fewer bytes than a header and a CRC): the same count")
          for op, mutant in (("swap<<=", "if (len <= 0) {"), ("constant+1", "if (len < 1) {"))),
        Equivalent("swap<<=", "for (std::size_t i = 0; i < n; ++i) samples_[i] = r.i16();",
                   "for (std::size_t i = 0; i <= n; ++i) samples_[i] = r.i16();",
                   "the one more sample read is the CRC's first two bytes, inside the raw buffer, "
                   "written to samples_[n], inside the samples buffer (it holds capacity / 2 "
                   "values, more than any frame's n); the frame's view holds n samples"),
        Equivalent("return true", "return false;  // every known type has returned above",
                   "return true;  // every known type has returned above",
                   "unreachable: parse refused unknown types first, and each case returns"),
        Equivalent("swap>>=", "if (d.first_sample > next_sample_) {",
                   "if (d.first_sample >= next_sample_) {",
                   "a DATA frame that starts exactly where the last ended then adds 0 lost "
                   "samples, and the reset branch (<) is not taken either way"),
    ],
    "python/eskin/deploy/target.py": [
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "machines = 1 if n_classes == 2 else n_classes",
                   "machines = 1 if n_classes <= 2 else n_classes",
                   "a model has at least two classes (the training data is refused otherwise)"),
        Equivalent("core/ReplaceComparisonOperator_Gt_NotEq", "while hi - lo > 1:",
                   "while hi - lo != 1:",
                   "the bisection keeps lo < hi, so hi - lo is at least 1"),
        *(Equivalent(op, "if not (m > n and a >= n):", mutant, _FULL_RANK)
          for op, mutant in (
              ("core/ReplaceComparisonOperator_Gt_NotEq", "if not (m != n and a >= n):"),
              ("core/ReplaceComparisonOperator_Gt_IsNot", "if not (m is not n and a >= n):"),
              ("core/ReplaceComparisonOperator_GtE_Eq", "if not (m > n and a == n):"),
              ("core/ReplaceComparisonOperator_GtE_Is", "if not (m > n and a is n):"))),
        Equivalent("core/NumberReplacer", "w = 1.0 / y", "w = 2.0 / y",
                   "weights scaled by a constant have the same least-squares solution"),
        *(Equivalent("core/NumberReplacer",
                     'if getattr(cfg, "window_samples", 0):  # a bounded window: fewer kept '
                     'samples per taxel',
                     f'if getattr(cfg, "window_samples", {d}):  # a bounded window: fewer kept '
                     'samples per taxel',
                     "cfg is a WindowConfig (made so just above), which always has the field")
          for d in (1, -1)),
        *(Equivalent(f"core/ReplaceComparisonOperator_GtE_{op}", "if len(others) >= len(_COEF):",
                     f"if len(others) {sym} len(_COEF):",
                     "the leave-one-grid-out fit: the calibration counts shipped hold four grids, "
                     "each leaving at least 12 counts for the 11 coefficients, so >, != and is "
                     "not are true wherever >= is")
          for op, sym in (("Gt", ">"), ("NotEq", "!="), ("IsNot", "is not"))),
        *(Equivalent("core/ReplaceComparisonOperator_Gt_NotEq", f"return {v} > 0",
                     f"return {v} != 0",
                     "window_samples is 0 or a positive count: a negative one is refused by "
                     "the core's window_config_resolve before the estimate (_ram_terms) and by "
                     "the loader of a compiled model, the two callers of _bounded")
          for v in ('float(window_config.get("window_samples", 0))',
                    'float(window_config.window_samples)')),
        *(Equivalent("core/NumberReplacer", f"return {v} > 0", f"return {v} > 1",
                     "window_samples is 0 or an even count of at least 2 (the core refuses 1)")
          for v in ('float(window_config.get("window_samples", 0))',
                    'float(window_config.window_samples)')),
        *(Equivalent("core/NumberReplacer", f"{d}[g] = max({d}.get(g, 0.0), abs({e} - y) / y)",
                     f"{d}[g] = max({d}.get(g, -1.0), abs({e} - y) / y)",
                     "the first error of a grid against -1 instead of 0: relative errors are "
                     "never negative, so the maximum is the same")
          for d, e in (("per_grid", "est"), ("grid_out", "g_est"))),
    ],
    "python/eskin/learn/calibration.py": [
        Equivalent("core/ReplaceTrueWithFalse",
                   "trk = np.intersect1d(tr, subsets[k], assume_unique=True)",
                   "trk = np.intersect1d(tr, subsets[k], assume_unique=False)",
                   "a fold's indices and a machine's subset are sets (sklearn's folds, "
                   "one_vs_all_indices): the same intersection"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if F.ndim == 1:", "if F.ndim <= 1:",
                   "decision values of no dimension fail at the next index either way (an "
                   "IndexError): there is no machine's column to read"),
        *(Equivalent(f"core/ReplaceComparisonOperator_Eq_{op}",
                     "if all(np.unique(y[tr]).size == n_classes for tr, _ in folds):",
                     f"if all(np.unique(y[tr]).size {sym} n_classes for tr, _ in folds):",
                     "a training part's classes are a subset of all (never more), counted in "
                     "Python ints: equal small counts are one object")
          for op, sym in (("GtE", ">="), ("Is", "is"))),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq",
                   "if np.unique(targets[trk, k]).size < 2:  # a small balanced subset: the "
                   "fold's whole part",
                   "if np.unique(targets[trk, k]).size != 2:  # a small balanced subset: the "
                   "fold's whole part",
                   "a machine's targets take two values (1 and 0): never more than 2 distinct"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Gt",
                   "if len({tuple(m.alphas_) for m in machines}) != 1:",
                   "if len({tuple(m.alphas_) for m in machines}) > 1:",
                   "a classifier has at least one machine: the set of its alphas is never empty"),
        Equivalent("core/NumberReplacer", "return _shared_distances(machines[0], X)",
                   "return _shared_distances(machines[ -1], X)",
                   "every machine has the same alpha (checked just above) and the classifier's "
                   "tensor shape: the first and the last give the same distances"),
        Equivalent("core/NumberReplacer",
                   "seed: int = 0, n_jobs: int | None = 1, notes: list[str] | None = None,",
                   "seed: int = 0, n_jobs: int | None = 2, notes: list[str] | None = None,",
                   "the folds' values are the same computed one or two at a time "
                   "(eskin.learn.parallel.run_calls keeps the order); only the time differs"),
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE",
                   "ab = [fit_sigmoid(F[:, k], (y == 1) if binary else (y == k)) for k in "
                   "range(F.shape[1])]",
                   "ab = [fit_sigmoid(F[:, k], (y >= 1) if binary else (y == k)) for k in "
                   "range(F.shape[1])]",
                   "a binary model's class indices are 0 and 1: y >= 1 is y == 1"),
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE", _TARGETS,
                   _TARGETS.replace("y == 1", "y >= 1"),
                   "a binary model's class indices are 0 and 1: y >= 1 is y == 1"),
        *(Equivalent("core/NumberReplacer", _CAL, _CAL.replace("0.0", t),
                     "the threshold only sets the flags, which this call discards")
          for t in ("1.0", "-1.0")),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if m == 0:  # reject 0, or no "
                   "confidence at all", "if m <= 0:  # reject 0, or no confidence at all",
                   "m = round(reject n) with 0 <= reject < 1 (checked above) is never negative"),
        *(Equivalent("core/NumberReplacer", _BIN, _BIN.replace(a, t), _ONE)
          for a, t in (("a[0]", "a[ -1]"), ("F[:, 0]", "F[:, -1]"), ("b[0]", "b[ -1]"))),
    ],
    "python/eskin/data/replay.py": [
        Equivalent("core/NumberReplacer",
                   "self.noise = 0.0 if noise_counts is None else float(noise_counts)",
                   "self.noise = 1.0 if noise_counts is None else float(noise_counts)",
                   "without noise_counts each taxel's own quiet level is used (self.levels): "
                   "self.noise is read only when noise_counts was given"),
        Equivalent("core/NumberReplacer", "contacts = np.full((n, 2), -1, dtype=np.int64)",
                   "contacts = np.full((n, 3), -1, dtype=np.int64)",
                   "only a recording's first two columns (onset, offset) are read: a third "
                   "column of -1 is never seen"),
        Equivalent("core/NumberReplacer", "q = max(2, min(300, r.shape[-1] // 10))",
                   "q = max( 1, min(300, r.shape[-1] // 10))",
                   "a line through one or two samples leaves nothing: a quiet noise of 0 "
                   "either way"),
        Equivalent("core/ReplaceBinaryOperator_Add_Sub",
                   "z = level + noise * self.rng.standard_normal((length, rows, cols))",
                   "z = level - noise * self.rng.standard_normal((length, rows, cols))",
                   "minus a standard normal draw is a standard normal draw: the gap's noise "
                   "has the same distribution, as from another seed"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Lt", "if lengths.min() != lengths.max():",
                   "if lengths.min() < lengths.max():",
                   "a minimum is never above the maximum"),
        *(Equivalent(f"core/ReplaceComparisonOperator_Lt_{op}",
                     "if len(raw) < _HEADER.size or raw[:8] != REPLAY_MAGIC:",
                     f"if len(raw) {sym} _HEADER.size or raw[:8] != REPLAY_MAGIC:",
                     "raw is a read of at most the header's 56 bytes: never more")
          for op, sym in (("NotEq", "!="), ("IsNot", "is not"))),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot", "if version != REPLAY_VERSION:",
                   "if version is not REPLAY_VERSION:",
                   "the version read is a Python int: 1 is one object (small integers are "
                   "cached), any other version is another object"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   '(length == 0, lambda i: f"length {int(length[i])} is 0"),',
                   '(length <= 0, lambda i: f"length {int(length[i])} is 0"),',
                   "a segment's length is an unsigned 64-bit field: never below 0"),
    ],
    "python/eskin/learn/evaluation.py": [
        Equivalent("core/NumberReplacer",
                   "np.add.at(per_group, (inv, y_true * k + y_pred), 1.0)",
                   "np.add.at(per_group, (inv, y_true * k + y_pred), 2.0)",
                   "every count of every group doubled: accuracy and recall are ratios of "
                   "counts, unchanged"),
        Equivalent("core/NumberReplacer",
                   "np.add.at(weights, (np.repeat(np.arange(int(n_boot)), G), draws.ravel()), "
                   "1.0)",
                   "np.add.at(weights, (np.repeat(np.arange(int(n_boot)), G), draws.ravel()), "
                   "2.0)",
                   "every draw counted twice: each resample's confusion doubled, its ratios "
                   "unchanged"),
        Equivalent("core/ReplaceTrueWithFalse",
                   "run_fold, [((t,), shared) for t in tasks], n_jobs=n_jobs, unordered=True",
                   "run_fold, [((t,), shared) for t in tasks], n_jobs=n_jobs, unordered=False",
                   "the pooled result sorts the records by fold: the order they finish in only "
                   "changes when on_fold hears of each (and one at a time it is the same)"),
        *(Equivalent("core/NumberReplacer", f"{name}: int = 1,", f"{name}: int = 2,",
                     "the folds, and the training within each, give the same results one or two "
                     "at a time (joblib keeps the order); only the time differs")
          for name in ("n_jobs", "inner_jobs")),
        Equivalent("core/ReplaceTrueWithFalse",
                   'extras=arrays["extras"], path=meta.path, _validated=True,',
                   'extras=arrays["extras"], path=meta.path, _validated=False,',
                   "the arrays are a validated campaign's, read from it: validating them again "
                   "passes (only the time differs)"),
        Equivalent("core/NumberReplacer",
                   'for key in records[0]["trained_with"] if records else ():',
                   'for key in records[ -1]["trained_with"] if records else ():',
                   "every fold record's trained_with has the same keys (trained_with() makes "
                   "one fixed dict): the first's are the last's"),
        *(Equivalent("core/NumberReplacer",
                     "out[key] = values[0] if all(v == values[0] for v in values) else values",
                     mutant,
                     "a setting every fold ran the same (each fold's value from the same field "
                     "of the same code, one type): the last is the first, and all equal to the "
                     "first is all equal to the last")
          for mutant in ("out[key] = values[ -1] if all(v == values[0] for v in values) else "
                         "values",
                         "out[key] = values[0] if all(v == values[ -1] for v in values) else "
                         "values")),
    ],
    "python/eskin/deploy/export.py": [
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", 'if spec.rule == "binary":',
                   'if spec.rule <= "binary":',
                   "the rule is 'binary' or 'one_vs_all' (checked just above): only 'binary' "
                   "sorts at or before 'binary'"),
        Equivalent("core/NumberReplacer", "m = spec.machines[0]", "m = spec.machines[ -1]",
                   "a binary model has exactly one machine (checked just above)"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Gt",
                   "if x.ndim != 4 or x.shape[1:3] != self.grid_shape:",
                   "if x.ndim > 4 or x.shape[1:3] != self.grid_shape:",
                   "signals of three axes were made four just above; of one or two, their shape "
                   "after the first axis is not the grid, and the same message refuses them"),
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE",
                   'real = np.dtype("<f8") if dtype == "float64" else np.dtype("<f4")',
                   'real = np.dtype("<f8") if dtype >= "float64" else np.dtype("<f4")',
                   "dtype is 'float32' or 'float64' (checked just above): only 'float64' sorts "
                   "at or after 'float64'"),
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE",
                   'flags = FLAG_FLOAT64 if dtype == "float64" else 0',
                   'flags = FLAG_FLOAT64 if dtype >= "float64" else 0',
                   "dtype is 'float32' or 'float64' (checked at the start): only 'float64' "
                   "sorts at or after 'float64'"),
        Equivalent("core/NumberReplacer", "owner = np.full(len(unique), -1)",
                   "owner = np.full(len(unique), - 2)",
                   "'no machine gave it yet' is any negative owner: it is only compared with 0"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", 'self.rule == "binary")',
                   'self.rule <= "binary")',
                   "a loaded model's rule is 'binary' or 'one_vs_all': only 'binary' sorts at "
                   "or before 'binary'"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "x = x[None] if x.ndim == 3 else x  # one recording: a batch of one",
                   "x = x[None] if x.ndim <= 3 else x  # one recording: a batch of one",
                   "signals of fewer than three axes are refused just below either way, with "
                   "the same message (it shows the shape given)"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "X = X[None] if X.ndim == 3 else X  # one pattern: a batch of one",
                   "X = X[None] if X.ndim <= 3 else X  # one pattern: a batch of one",
                   "patterns of fewer than three axes are refused by the core either way, with "
                   "the same message (the shape it expects)"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Lt",
                   "bad = np.flatnonzero(np.asarray(status) != 0)",
                   "bad = np.flatnonzero(np.asarray(status) < 0)",
                   "the batch classifiers return 0 or a negative status (kDecision, 1, is the "
                   "stream's alone)"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   'return v.ravel() if self.rule == "binary" else v',
                   'return v.ravel() if self.rule <= "binary" else v',
                   "a loaded model's rule is 'binary' or 'one_vs_all': only 'binary' sorts at "
                   "or before 'binary'"),
        Equivalent("core/NumberReplacer", "x = x.reshape(-1, x.shape[-1]).T",
                   "x = x.reshape(- 2, x.shape[-1]).T",
                   "numpy infers the size given as any negative number (-2 as -1)"),
        Equivalent("core/ReplaceAndWithOr",
                   'if hasattr(cfg, "to_array") and hasattr(cfg, "field_names"):',
                   'if hasattr(cfg, "to_array") or hasattr(cfg, "field_names"):',
                   "a window configuration is an eskin.WindowConfig (both methods) or a plain "
                   "mapping (neither)"),
        *(Equivalent("core/NumberReplacer", "chunk: int = 32) -> list[dict[str, Any]]:",
                     f"chunk: int = {n}) -> list[dict[str, Any]]:",
                     "how many recordings predict_recordings reads at a time: each is decided on "
                     "its own samples, so every output is the same for any chunk "
                     "(test_per_recording_decisions_do_not_depend_on_how_many_are_read_at_a_time)")
          for n in (31, 33)),
    ],
    "python/eskin/link/receiver.py": [
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE",
                   "if (s is not None and s.state == StreamState.FINISHED and st is not None",
                   "if (s is not None and s.state >= StreamState.FINISHED and st is not None",
                   "FINISHED is the last of the three states, and a STATUS of another state "
                   "is refused by the decoder"),
        *(Equivalent("core/NumberReplacer",
                     "if data_run and data_run[0].samples.shape[1:] != f.samples.shape[1:]:",
                     f"if data_run and data_run[0].samples.shape[ {a}:] != f.samples.shape[1:]:",
                     "a shape of another length is never equal: every DATA frame its own run, "
                     "and runs cut finer are fed the same, frame by frame in order")
          for a in ("2", "0")),
        *(Equivalent("core/NumberReplacer",
                     "if data_run and data_run[0].samples.shape[1:] != f.samples.shape[1:]:",
                     f"if data_run and data_run[0].samples.shape[1:] != f.samples.shape[ {a}:]:",
                     "a shape of another length is never equal: every DATA frame its own run, "
                     "and runs cut finer are fed the same, frame by frame in order")
          for a in ("2", "0")),
        *(Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot", line, mutant,
                     "the decoded version is a Python int; two different values are never one "
                     "object, and CPython keeps one object for each int up to 256, the version "
                     "this host speaks among them: `is not` is `!=`")
          for line, mutant in (
              ("foreign = isinstance(f, InfoFrame) and f.protocol_version != PROTOCOL_VERSION",
               "foreign = isinstance(f, InfoFrame) and f.protocol_version is not "
               "PROTOCOL_VERSION"),
              ("if f.protocol_version != PROTOCOL_VERSION:",
               "if f.protocol_version is not PROTOCOL_VERSION:"))),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   "if data_run and data_run[0].samples.shape[1:] != f.samples.shape[1:]:",
                   "if data_run and data_run[0].samples.shape[1:] is not f.samples.shape[1:]:",
                   "two frames' shapes are never the same tuple object: every DATA frame its "
                   "own run, and runs cut finer are fed the same, frame by frame in order"),
        Equivalent("core/ReplaceComparisonOperator_Eq_Is",
                   "if (s is not None and s.state == StreamState.FINISHED and st is not None",
                   "if (s is not None and s.state is StreamState.FINISHED and st is not None",
                   "a decoded STATUS's state is a StreamState member, and each member is one "
                   "object"),
        *(Equivalent("core/ReplaceComparisonOperator_Eq_GtE", line,
                     line.replace('record_policy == "touch"', 'record_policy >= "touch"'),
                     'the policy is "touch" or "segment" (the listener refuses any other), and '
                     '"segment" sorts before "touch": `>=` is `==` for both')
          for line in ('if self.recorder is not None and self.record_policy == "touch" and not '
                       'classifiers:',
                       'if self.recorder is not None and self.record_policy == "touch":',
                       'if self.record_policy == "touch":')),
        Equivalent("core/ReplaceComparisonOperator_Gt_NotEq",
                   "if self.info is not None and self.info.volts_per_count > 0:",
                   "if self.info is not None and self.info.volts_per_count != 0:",
                   "an INFO frame whose volts_per_count is negative is refused (FrameChecks): "
                   "the one kept is at least 0"),
        Equivalent("core/NumberReplacer",
                   'd["lost_samples"] = max((st.lost_samples if st else 0) + self._tail, '
                   'self._unseen)',
                   'd["lost_samples"] = max((st.lost_samples if st else -1) + self._tail, '
                   'self._unseen)',
                   "without a stream the tail is 0 (finish sets it only with one) and the "
                   "unseen count is at least 0: max(-1, that) is max(0, that)"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   "return status.state != StreamState.STREAMING and 1 <= status.connections "
                   "<= 1 + reconnects",
                   "return status.state is not StreamState.STREAMING and 1 <= status.connections "
                   "<= 1 + reconnects",
                   "a decoded STATUS's state is a StreamState member (the decoder makes it one), "
                   "and an enumeration's members are singletons"),
        Equivalent("core/ReplaceComparisonOperator_Gt_GtE",
                   "and st.next is not None and s.next_sample > st.next and not self._tail):",
                   "and st.next is not None and s.next_sample >= st.next and not self._tail):",
                   "at equality the tail is 0 samples, and self._tail is 0 there already"),
        *(Equivalent("core/NumberReplacer",
                     "grid = (int(frames[0].samples.shape[1]), int(frames[0].samples.shape[2]))",
                     mutant, "the frames of one call are of one grid (feed cuts its runs where "
                     "it changes): the first and the last have the same rows and columns")
          for mutant in (
              "grid = (int(frames[ -1].samples.shape[1]), int(frames[0].samples.shape[2]))",
              "grid = (int(frames[0].samples.shape[1]), int(frames[ -1].samples.shape[2]))")),
        Equivalent("core/NumberReplacer",
                   "if data_run and data_run[0].samples.shape[1:] != f.samples.shape[1:]:",
                   "if data_run and data_run[ -1].samples.shape[1:] != f.samples.shape[1:]:",
                   "the frames of a run are of one grid (the run is cut where it changes): its "
                   "first and last have the same shape"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", 'if self.record_policy == "touch":',
                   'if self.record_policy <= "touch":',
                   "the policy is 'touch' or 'segment' (checked by LinkListener), so <= also "
                   "writes 'segment' recordings at a restart: Recorder.ready ignores final for "
                   "segments, and the history is unchanged since the on_fed() that follows each "
                   "piece fed, so that call writes nothing"),
        *(Equivalent("core/ReplaceComparisonOperator_Is_Eq", ln, ln.replace(" is ", " == ", 1),
                     "HostClassifier defines no __eq__: == between two of them (or one and None) "
                     "is identity")
          for ln in ("if c is self.classifier:",
                     "name = c.label(t) if c is self.classifier and not t.dont_know else None")),
    ],
    "python/eskin/link/protocol.py": [
        Equivalent("core/ReplaceFalseWithTrue", "@dataclass(frozen=True, eq=False)",
                   "@dataclass(frozen=True, eq=True)",
                   "DataFrame defines its own __eq__, which the dataclass keeps either way; "
                   "eq=True only adds a hash of its fields, unhashable too (a numpy array), "
                   "where __hash__ = None says so first"),
    ],
    "python/eskin/data/campaign.py": [
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if value.ndim == 0:",
                   "if value.ndim <= 0:", "an array's number of axes is never negative"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if len(rows) == 0:",
                   "if len(rows) <= 0:", "a length is never negative"),
        Equivalent("core/ReplaceComparisonOperator_Eq_Lt",
                   "if np.all(np.diff(uniq) == 1):  # one recording, or a run of them: one read",
                   "if np.all(np.diff(uniq) < 1):  # one recording, or a run of them: one read",
                   _READS),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "if np.all(np.diff(uniq) == 1):  # one recording, or a run of them: one read",
                   "if np.all(np.diff(uniq) <= 1):  # one recording, or a run of them: one read",
                   _READS),
        Equivalent("core/NumberReplacer",
                   "if np.all(np.diff(uniq) == 1):  # one recording, or a run of them: one read",
                   "if np.all(np.diff(uniq) == 0):  # one recording, or a run of them: one read",
                   _READS),
        Equivalent("core/NumberReplacer", "data = self._read(rows)[0]",
                   "data = self._read(rows)[ -1]", "the read holds exactly one recording"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if idx.dtype == bool:",
                   "if idx.dtype <= bool:", "bool is the only type that casts safely to bool"),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq",
                   "elif isinstance(obj, h5py.Group) and depth < 8:",
                   "elif isinstance(obj, h5py.Group) and depth != 8:",
                   "the walk's depth starts at 0 and grows by one: it meets 8 before passing it"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot", "if ds.dtype != expected:",
                   "if ds.dtype is not expected:",
                   "numpy's dtypes of the built-in types are single objects: a stored type equal "
                   "to the expected one is that object (h5py returns it)"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Gt", _PATCH,
                   _PATCH.replace("shape !=", "shape >"),
                   "every extra field has n entries (checked before): its shape is (n,) or "
                   "(n, ...), never less than (n,)"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Lt", _PATCH,
                   _PATCH.replace('kind !=', 'kind <'),
                   "every numpy kind letter but u sorts before u"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot", _PATCH,
                   _PATCH.replace('kind !=', 'kind is not'),
                   "one-letter strings are single objects in CPython"),
        Equivalent("core/NumberReplacer",
                   "planes = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 2).T.tobytes()",
                   "planes = np.frombuffer(raw, dtype=np.uint8).reshape(- 2, 2).T.tobytes()",
                   "numpy takes any negative size in a reshape for the one it works out"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   "or enc.compression_level != self.compression_level):",
                   "or enc.compression_level is not self.compression_level):",
                   "a compression level is None or an int from 0 to 9: single objects in CPython"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", _EXIT,
                   _EXIT.replace("_n == 0", "_n <= 0"),
                   "a count of recordings is never negative"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", _EXIT,
                   _EXIT.replace("on_error ==", "on_error <="),
                   "on_error is 'keep' or 'discard' (checked when the writer is made): only "
                   "'discard' sorts at or before 'discard'"),
        Equivalent("core/ReplaceAndWithOr", 'if exc is not None and hasattr(exc, "add_note"):',
                   'if exc is not None or hasattr(exc, "add_note"):',
                   "on Python 3.11 and later (the interpreter of make test) every exception has "
                   "add_note; the check is there for 3.9 and 3.10"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if n == 0:", "if n <= 0:",
                   "a number of recordings is never negative"),
        Equivalent("core/ReplaceComparisonOperator_Is_IsNot",
                   "load_campaign(tmp, check_data=held is None).close()",
                   "load_campaign(tmp, check_data=held is not None).close()",
                   "whether the built file's chunks are read back once more before it is "
                   "placed: they were just written from records whose CRC-32 was checked, so "
                   "the reading finds nothing either way and the same file is placed"),
        Equivalent("core/ReplaceComparisonOperator_Gt_NotEq",
                   'return f" ({bad.size} bad entries)" if bad.size > 1 else ""',
                   'return f" ({bad.size} bad entries)" if bad.size != 1 else ""',
                   "the count of bad entries is asked for only when there is at least one"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   "if version != FORMAT_VERSION:", "if version is not FORMAT_VERSION:",
                   "the version read is a Python int: equal small ints are one object, and "
                   "unequal ones are different objects"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Lt",
                   "if len(set(mods)) != len(mods):", "if len(set(mods)) < len(mods):",
                   "the set of a list's names never has more entries than the list"),
        Equivalent("core/ReplaceTrueWithFalse", "_validated=True)", "_validated=False)",
                   "the loader's campaign built with its fields checked again: the loader has "
                   "checked them (the same checks, strict dtypes), so the same campaign"),
    ],
    "python/eskin/data/journal.py": [
        Equivalent("core/ReplaceComparisonOperator_Lt_IsNot", _HEAD,
                   _HEAD.replace("len(head) <", "len(head) is not"), _HEAD_WHY),
        Equivalent("core/ReplaceComparisonOperator_Lt_Gt", _TEXT,
                   _TEXT.replace("len(text) <", "len(text) >"), _TEXT_WHY),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq", _TEXT,
                   _TEXT.replace("len(text) <", "len(text) !="), _TEXT_WHY),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq", _TEXT,
                   _TEXT.replace("len(crc) <", "len(crc) !="),
                   "the CRC is a read of 4 bytes: never more"),
        Equivalent("core/ReplaceComparisonOperator_Lt_IsNot", "if len(head) < _RECORD_HEAD.size:",
                   "if len(head) is not _RECORD_HEAD.size:", _RHEAD_WHY),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq", "if len(head) < _RECORD_HEAD.size:",
                   "if len(head) != _RECORD_HEAD.size:", _RHEAD_WHY),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq", "while pos < self.size:",
                   "while pos != self.size:",
                   "each record is read within the bytes left (a longer one is torn and ends "
                   "the walk), so the position reaches the journal's size and never passes it"),
        Equivalent("core/NumberReplacer", "self._fd = -1", "self._fd = - 2",
                   "the released writer's descriptor: only ever tested for >= 0"),
        *(Equivalent("core/NumberReplacer",
                     "record, reason = _read_record(self._fh, None, 1 << 62)",
                     f"record, reason = _read_record(self._fh, None, {bound})",
                     "the bound of a record read by index, no bound in practice: a journal "
                     "file is never 2^61 bytes long")
          for bound in ("2 << 62", "1 << 63", "1 << 61")),
        *(Equivalent("core/NumberReplacer", ln, ln.replace("unpack(crc)[0]", "unpack(crc)[ -1]"),
                     "a CRC unpacked by a one-field struct: a tuple of one, whose first is its "
                     "last")
          for ln in ("if len(text) < n or len(crc) < 4 or _CRC.unpack(crc)[0] != "
                     "zlib.crc32(text):",
                     "if _CRC.unpack(crc)[0] != zlib.crc32(body, zlib.crc32(text, "
                     "zlib.crc32(head[4:]))):")),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq",
                   "if len(head) < len(HEADER_MAGIC) + 4 or head[: len(HEADER_MAGIC)] != "
                   "HEADER_MAGIC:",
                   "if len(head) != len(HEADER_MAGIC) + 4 or head[: len(HEADER_MAGIC)] != "
                   "HEADER_MAGIC:",
                   "head is fh.read(len(HEADER_MAGIC) + 4): never longer, so != is <"),
        Equivalent("core/NumberReplacer",
                   "v.decode() if isinstance(v, bytes) else str(v) for v in "
                   "arr.reshape(-1).tolist()",
                   "v.decode() if isinstance(v, bytes) else str(v) for v in "
                   "arr.reshape(- 2).tolist()",
                   "numpy takes any negative size as the one unknown dimension: reshape(-2) "
                   "flattens as reshape(-1) does"),
    ],
    "python/eskin/learn/recipes.py": [
        *(Equivalent("core/NumberReplacer",
                     "rng = np.random.default_rng(np.random.SeedSequence([self.seed, 22]))",
                     f"rng = np.random.default_rng(np.random.SeedSequence([self.seed, {k}]))",
                     "the key only keeps the first candidates' draw apart from the seed's other "
                     "uses (the splits); another constant does the same: another sample, as "
                     "random and as reproducible, which no test can prefer without fixing the "
                     "draw itself") for k in (21, 23)),
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE",
                   "return np.where(y == 1, 1.0, -1.0)[:, None]",
                   "return np.where(y >= 1, 1.0, -1.0)[:, None]",
                   "two classes are labelled 0 and 1 (the class indices of the training set)"),
      *(Equivalent("core/NumberReplacer",
                     'reach, trained = _kernel_reach(blocks) if recipe.machine == "svm" else '
                     '(math.inf, 0)',
                     'reach, trained = _kernel_reach(blocks) if recipe.machine == "svm" else '
                     f'(math.inf, {v})',
                     "an RLS candidate's reach is infinite: it never collapses, and the count "
                     "beside it is never read") for v in ("1", "-1")),
        Equivalent("core/ReplaceComparisonOperator_Lt_Is",
                   "if len(support) and np.max(np.abs(beta[support])) < 1.0 / c.lam:",
                   "if len(support) and np.max(np.abs(beta[support])) is 1.0 / c.lam:",
                   "never keeping a fit with no coefficient at its bound C for the larger C's: "
                   "each is then fitted, to the same solution (its optimality conditions do not "
                   "involve C); only the time differs"),
        *(Equivalent("core/NumberReplacer", "kv[0][1] or 0)):", t,
                     "the order in which a task scores its kernels (sigma, amplitude): each "
                     "candidate's error, support vectors and collapse come from its own kernel's "
                     "blocks only, and each lands under its own (candidate, split) key")
          for t in ("kv[0][ 0] or 0)):", "kv[0][1] or 1)):", "kv[0][1] or -1)):")),
        *(Equivalent("core/NumberReplacer",
                     'smallest = distance_plan(dims, alphas, 8, 8)["pack_bytes"]  # a row and a '
                     'column block of 8',
                     f'smallest = distance_plan(dims, alphas, {a}, {b})["pack_bytes"]  # a row and '
                     'a column block of 8',
                     "a plan's block holds the larger of its two counts of patterns: 7 against "
                     "8 is planned as 8 against 8, the same bytes")
          for a, b in (("7", "8"), ("8", "7"))),
        Equivalent("core/NumberReplacer",
                   'smallest = distance_plan(dims, alphas, 8, 8, max_bytes=smallest - 1)'
                   '["pack_bytes"]',
                   'smallest = distance_plan(dims, alphas, 8, 8, max_bytes=smallest - 2)'
                   '["pack_bytes"]',
                   "a plan packs whole doubles: its bytes are a multiple of 8, and none lies "
                   "between smallest - 2 and smallest - 1"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if F.shape[0] == 0:",
                   "if F.shape[0] <= 0:", "an array's length is never negative"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", "if se == 0.0:", "if se <= 0.0:",
                   "a square root is never negative"),
        *(Equivalent("core/ReplaceComparisonOperator_Eq_LtE", f"if n_classes == 2:  # {c}",
                     f"if n_classes <= 2:  # {c}",
                     "RecipeSearch.fit refuses fewer than two classes: n_classes is never "
                     "below 2")
          for c in ("one machine, on every pattern", "its target +1 is class 1",
                    "the sign of the one machine")),
        *(Equivalent(f"core/ReplaceComparisonOperator_Eq_{op}", 'if neg == "all":',
                     f'if neg {sym} "all":',
                     "every negative by the other branch: each machine's subset is every "
                     "pattern, cut to the split's training part, the same indices as separate "
                     "arrays (only the sharing of their Gram blocks is lost)")
          for op, sym in (("Lt", "<"), ("LtE", "<="))),
        Equivalent("core/ReplaceComparisonOperator_Eq_GtE",
                   "mine = [c for c in cands if c.recipe == recipe]",
                   "mine = [c for c in cands if c.recipe >= recipe]",
                   "the recipes are taken in sorted order: a candidate of a larger recipe, "
                   "scored first with a smaller one's machines, is scored again in its own "
                   "recipe's turn, which overwrites the result"),
        Equivalent("core/ReplaceComparisonOperator_Eq_Is",
                   "mine = [c for c in cands if c.recipe == recipe]",
                   "mine = [c for c in cands if c.recipe is recipe]",
                   "every candidate of a recipe holds the one Recipe object of the search's "
                   "(deduplicated) recipes, and a task's candidates travel to it in one pickle, "
                   "which keeps that identity"),
        *(Equivalent(f"core/ReplaceComparisonOperator_Eq_{op}",
                     'if recipe.machine == "rls" and recipe.negatives == "all":',
                     f'if recipe.machine {sym} "rls" and recipe.negatives == "all":',
                     "tensor-RLS with every negative by the other branch: its machines fitted one "
                     "by one instead of through one shared factorisation, the same machines")
          for op, sym in (("Lt", "<"), ("LtE", "<="))),
        *(Equivalent(f"core/ReplaceComparisonOperator_Eq_{op}",
                     'if recipe.machine == "rls" and recipe.negatives == "all":',
                     f'if recipe.machine == "rls" and recipe.negatives {sym} "all":',
                     "tensor-RLS with every negative by the other branch: its machines fitted one "
                     "by one instead of through one shared factorisation, the same machines")
          for op, sym in (("Lt", "<"), ("LtE", "<="))),
        Equivalent("core/NumberReplacer", "_, Ktr, Kte = blocks[0]", "_, Ktr, Kte = blocks[ -1]",
                   "with every negative the machines' blocks are one shared tuple: the last is "
                   "the first"),
        Equivalent("core/ReplaceTrueWithFalse",
                   "B = linalg.cho_solve(linalg.cho_factor(A, lower=True, check_finite=False),",
                   "B = linalg.cho_solve(linalg.cho_factor(A, lower=False, check_finite=False),",
                   "the upper Cholesky factor instead of the lower: the same solve (cho_solve "
                   "reads which one it is given), equal to rounding"),
        Equivalent("core/ReplaceFalseWithTrue",
                   "B = linalg.cho_solve(linalg.cho_factor(A, lower=True, check_finite=False),",
                   "B = linalg.cho_solve(linalg.cho_factor(A, lower=True, check_finite=True),",
                   "SciPy's check for infinities and NaN on a Gram matrix of finite kernel "
                   "values: only the time differs"),
        Equivalent("core/ReplaceFalseWithTrue", "Y[tr], check_finite=False)",
                   "Y[tr], check_finite=True)",
                   "SciPy's check for infinities and NaN on -1/+1 targets: only the time "
                   "differs"),
        *(Equivalent("core/NumberReplacer",
                     "results[i] = (1.0, trained, True)  # collapsed whatever the fit: none is made",
                     f"results[i] = ( {v}, trained, True)  # collapsed whatever the fit: none is "
                     "made",
                     "a collapsed split's error is set to 1.0 where the scores are recorded "
                     "(_record_scores), whatever the task returned for it")
          for v in ("2.0", "0.0")),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE", 'if recipe.machine == "rls":',
                   'if recipe.machine <= "rls":',
                   'a machine is "rls" or "svm", and "svm" sorts after "rls"'),
        Equivalent("core/ReplaceComparisonOperator_Lt_Gt",
                   "if len(support) and np.max(np.abs(beta[support])) < 1.0 / c.lam:",
                   "if len(support) and np.max(np.abs(beta[support])) > 1.0 / c.lam:",
                   "no coefficient exceeds its bound C: no fit is kept for the larger C's, each "
                   "is fitted, to the same solution (only the time differs)"),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq",
                   "if len(support) and np.max(np.abs(beta[support])) < 1.0 / c.lam:",
                   "if len(support) and np.max(np.abs(beta[support])) != 1.0 / c.lam:",
                   "no coefficient exceeds its bound C (the solver keeps them in [0, C]): "
                   "below it is not equal to it"),
        Equivalent("core/ReplaceFalseWithTrue",
                   "_, x, info = linalg.lapack.dposv(A, y, lower=False, overwrite_a=True)",
                   "_, x, info = linalg.lapack.dposv(A, y, lower=True, overwrite_a=True)",
                   "K + lambda I is symmetric: the Cholesky factor of its lower triangle is the "
                   "transpose of its upper one's, the same solve to rounding"),
        Equivalent("core/ReplaceTrueWithFalse",
                   "_, x, info = linalg.lapack.dposv(A, y, lower=False, overwrite_a=True)",
                   "_, x, info = linalg.lapack.dposv(A, y, lower=False, overwrite_a=False)",
                   "A is a temporary the solver may overwrite or copy: only the memory differs"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Gt", "if info != 0:", "if info > 0:",
                   "LAPACK's negative info names an illegal argument, and the arguments are "
                   "always legal (a square matrix and a vector of its size)"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "made[id(trk)] = math.inf if Kte.shape[0] == 0 else "
                   "float(Kte.sum(axis=1).max())",
                   "made[id(trk)] = math.inf if Kte.shape[0] <= 0 else "
                   "float(Kte.sum(axis=1).max())",
                   "an array's length is never negative"),
        Equivalent("core/ReplaceTrueWithFalse", "fits: bool = True", "fits: bool = False",
                   "a row's fits is read under a budget only, and _check_budget sets it when "
                   "the row is scored, before any read"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Gt",
                   'return (f"{n} candidate{\'s\' if n != 1 el'
                   'se \'\'} had a collapsed kernel on {splits} "',
                   'return (f"{n} candidate{\'s\' if n > 1 els'
                   'e \'\'} had a collapsed kernel on {splits} "',
                   "the note is made for one candidate at least (None for none): n is never 0"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_Gt",
                   'f"split{\'s\' if splits != 1 else \'\'} (a machi'
                   'ne\'s held-out decision values all within "',
                   'f"split{\'s\' if splits > 1 else \'\'} (a machi'
                   'ne\'s held-out decision values all within "',
                   "a candidate in the note collapsed on one split at least: the count of "
                   "splits is never 0"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "family = [c for c in alive if key(c.recipe) == top]",
                   "family = [c for c in alive if key(c.recipe) <= top]",
                   "top is the smallest key of the candidates: none is below it"),
        Equivalent("core/NumberReplacer", "n_jobs: int | None = 1,", "n_jobs: int | None = 2,",
                   "two joblib workers by default instead of one: the results are the same for "
                   "any n_jobs (tests/python/learn/test_parallel.py), only the time differs"),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "if r == 0 and self.significance is not None and alive:",
                   "if r <= 0 and self.significance is not None and alive:",
                   "r counts the rounds from 0 (enumerate): never below it"),
        *(Equivalent(f"core/ReplaceComparisonOperator_Lt_{op}", "if r < len(schedule) - 1:",
                     f"if r {sym} len(schedule) - 1:",
                     "r runs from 0 to len(schedule) - 1: below the last is not the last")
          for op, sym in (("NotEq", "!="), ("IsNot", "is not"))),
        Equivalent("core/ReplaceComparisonOperator_Eq_LtE",
                   "mine = [c for c in ranked if key(c.recipe) == top]",
                   "mine = [c for c in ranked if key(c.recipe) <= top]",
                   "top is the smallest key of the ranked candidates: none is below it"),
        Equivalent("core/ReplaceComparisonOperator_Eq_Is",
                   "mine = [c for c in final if c.recipe == recipe]",
                   "mine = [c for c in final if c.recipe is recipe]",
                   "every candidate of a recipe holds the one Recipe object of the search's "
                   "(deduplicated) recipes, which _preferred_recipe returns"),
        Equivalent("core/ReplaceComparisonOperator_LtE_Lt",
                   "tied = [c for c in mine if rows[c].mean <= best_err + tolerance + 1e-12]",
                   "tied = [c for c in mine if rows[c].mean < best_err + tolerance + 1e-12]",
                   "`<` differs only for a mean error equal to the lowest plus the tolerance plus "
                   "1e-12 to the bit; a mean exactly one held-out pattern above is tied either "
                   "way (tested)"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   "self.ranking_ = [entry(best)] + [entry(c) for c in final if c != best]",
                   "self.ranking_ = [entry(best)] + [entry(c) for c in final if c is not best]",
                   "best is one of the objects of final (picked from it), and final holds each "
                   "candidate once"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   'others = [e for e in self.recipe_table_ if e["candidate"].recipe != '
                   'self.best_.recipe]',
                   'others = [e for e in self.recipe_table_ if e["candidate"].recipe is not '
                   'self.best_.recipe]',
                   "every candidate of a recipe holds the one Recipe object of the search's "
                   "(deduplicated) recipes"),
        Equivalent("core/ReplaceComparisonOperator_Lt_NotEq",
                   "if np.unique(y[tr]).size < np.unique(y).size:",
                   "if np.unique(y[tr]).size != np.unique(y).size:",
                   "a training part's classes are a subset of all: never more of them"),
        Equivalent("core/ReplaceComparisonOperator_NotEq_IsNot",
                   "if sigma != self._exp_sigma:", "if sigma is not self._exp_sigma:",
                   "the Gaussians of a sigma recomputed when an equal sigma is another float "
                   "object: the same values, only the time differs"),
    ],
}


#: This interpreter without scikit-build-core's editable-install finder (`make install` puts
#: one in the venv, ahead of PYTHONPATH: the tests would import the work tree's eskin, not the
#: mutated copy's): `python -c` that drops it, then runs the module or code given after it.
PYTHON = [sys.executable, "-c",
          "import runpy, sys; sys.meta_path[:] = [f for f in sys.meta_path "
          "if type(f).__name__ != 'ScikitBuildRedirectingFinder']; "
          "a = sys.argv[1:]; sys.argv = a[1:]; "
          "runpy.run_module(a[1], run_name='__main__', alter_sys=True) if a[0] == '-m' "
          "else exec(a[1])"]


def nice() -> list[str]:
    return ["nice", "-n", "10"] if shutil.which("nice") else []


def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """The Wilson score interval (95 % by default) of a rate of k successes in n trials."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    centre = p + z * z / (2 * n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    den = 1 + z * z / n
    return max(0.0, (centre - half) / den), min(1.0, (centre + half) / den)


def report(module: str, n: int, killed: int, generated: int, note: str = "",
           equivalent: int = 0) -> float | None:
    """Prints the module's line; its score (None when no mutant ran)."""
    lo, hi = wilson(killed, n)
    score = f"{killed / n:.2f}" if n else "-"
    print(f"MUTATION: module={module} mutants={n} killed={killed} score={score} "
          f"ci95=[{lo:.2f}, {hi:.2f}] generated={generated} equivalent={equivalent}{note}",
          flush=True)
    return killed / n if n else None


def choose(mutants: list, sample: int | None, seed: int, module: str) -> list:
    """The mutants that run: all of them, or a random ``sample`` drawn with ``seed`` (each
    module its own draw: two modules of the same size do not get the same positions), in the
    module's order."""
    if sample is None or len(mutants) <= sample:
        return list(mutants)
    picked = sorted(random.Random(f"{seed}/{module}").sample(range(len(mutants)), sample))
    return [mutants[i] for i in picked]


def changed_lines(diff: str) -> dict[str, set[int]]:
    """The lines of the new side of a ``git diff -U0`` that a change touches, by file: the
    added or changed lines, and around a deletion the lines on either side of it."""
    out: dict[str, set[int]] = {}
    current: set[int] | None = None
    for line in diff.splitlines():
        if line.startswith("+++ "):
            path = line[4:].strip()
            current = None if path == "/dev/null" else out.setdefault(
                path[2:] if path.startswith("b/") else path, set())
        elif line.startswith("@@ ") and current is not None:
            m = re.match(r"@@ -\d+(?:,\d+)? \+(\d+)(?:,(\d+))? @@", line)
            if m is None:
                continue
            start, count = int(m.group(1)), int(m.group(2) or 1)
            if count == 0:  # a deletion after line `start`
                current.update(x for x in (start, start + 1) if x > 0)
            else:
                current.update(range(start, start + count))
    return out


def default_base() -> str:
    """The merge-base of HEAD with main, or HEAD~1 when HEAD is on main (or there is none)."""
    def git(*a: str) -> str:
        r = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True)
        return r.stdout.strip() if r.returncode == 0 else ""
    head = git("rev-parse", "HEAD")
    base = git("merge-base", "HEAD", "main")
    return base if base and base != head else "HEAD~1"


def diff_lines(base: str) -> dict[str, set[int]]:
    """The lines of the work tree (committed or not) that differ from ``base``, by file."""
    r = subprocess.run(["git", "diff", "-U0", "--no-color", "--no-ext-diff", base, "--"],
                       cwd=REPO, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"mutation: git diff {base}: {r.stderr.strip()}")
    return changed_lines(r.stdout)


def copy_tree(dst: Path) -> None:
    """The tracked files of the work tree (and the compiled module) copied to ``dst``."""
    if dst.exists():
        shutil.rmtree(dst)
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, check=True,
                           capture_output=True).stdout.decode().split("\0")
    for f in filter(None, files):
        src = REPO / f
        if src.is_file():
            (dst / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / f)
    for so in (REPO / "python" / "eskin").glob("_core*.so"):
        shutil.copy2(so, dst / "python" / "eskin" / so.name)


# ------------------------------------------------------------------------------------ Python


def annotation_spans(source: str) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """(start, end) (line, column) of every type annotation of a module: a mutant inside one
    changes no behaviour (the modules use ``from __future__ import annotations``: annotations
    are never evaluated), so none is run (mutmut does not make them either)."""
    spans = []
    for node in ast.walk(ast.parse(source)):
        found = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            found.append(node.returns)
            a = node.args
            found += [x.annotation for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
            found += [x.annotation for x in (a.vararg, a.kwarg) if x is not None]
        elif isinstance(node, ast.AnnAssign):
            found.append(node.annotation)
        spans += [((n.lineno, n.col_offset), (n.end_lineno, n.end_col_offset))
                  for n in found if n is not None]
    return spans


def in_annotation(pos: tuple[int, int], spans: list) -> bool:
    return any(start <= tuple(pos) < end for start, end in spans)


def parameter_lists(source: str) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Where each function's parameters are written, minus their defaults and annotations:
    a ``*`` or ``/`` there is a marker (keyword-only or positional-only parameters follow),
    which cosmic-ray's binary-operator families take for an operator."""
    def span(n: ast.AST) -> tuple[tuple[int, int], tuple[int, int]]:
        return (n.lineno, n.col_offset), (n.end_lineno, n.end_col_offset)

    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            body = node.body if isinstance(node, ast.Lambda) else node.body[0]
            cut = [span(d) for d in (*node.args.defaults, *node.args.kw_defaults) if d]
            cut += [span(a.annotation) for a in (*node.args.posonlyargs, *node.args.args,
                                                  *node.args.kwonlyargs, node.args.vararg,
                                                  node.args.kwarg) if a and a.annotation]
            start = (node.lineno, node.col_offset)
            for lo, hi in sorted(cut):
                out.append((start, lo))
                start = hi
            out.append((start, (body.lineno, body.col_offset)))
    return out


def is_parameter_marker(rows: list[str], pos: tuple[int, int], lists: list) -> bool:
    """The mutated character is a ``*`` or ``/`` inside one of ``lists``."""
    return rows[pos[0] - 1][pos[1]:pos[1] + 1] in ("*", "/") and in_annotation(pos, lists)


def is_equivalent(module: str, operator: str, line: str, mutated) -> bool:
    """Whether a mutant of ``module`` (its operator, its line as the module has it, and a
    function giving the line as the mutant has it) is one of the module's EQUIVALENT."""
    entries = [e for e in EQUIVALENT.get(module, ())
               if e.operator == operator and e.line == line.strip()]
    return bool(entries) and mutated().strip() in {e.mutant for e in entries}


def python_mutant_source(source: str, mutation) -> str | None:
    """``source`` with a cosmic-ray mutation applied (None: it cannot be applied)."""
    from cosmic_ray.mutating import mutate_code
    from cosmic_ray.plugins import get_operator

    operator = get_operator(mutation.operator_name)(**(mutation.operator_args or {}))
    return mutate_code(source, operator, mutation.occurrence)


def python_mutant_line(source: str, mutation) -> str:
    """The line of ``source`` that a cosmic-ray mutation changes, as the mutant has it."""
    code = python_mutant_source(source, mutation)
    return "" if code is None else code.splitlines()[mutation.start_pos[0] - 1]


def python_mutants(module: str, work: Path, env: dict, command: list[str],
                   lines: set[int] | None) -> tuple[list, int, int]:
    """cosmic-ray's mutants of ``module`` in the copy ``work`` (those on ``lines`` only, when
    given) of the operator families run, outside annotations, in the module's order; with how
    many were generated and how many of them are listed as equivalent (left out)."""
    from cosmic_ray.work_db import WorkDB, use_db

    name = module.replace("/", "_")
    session = OUT / (name + ".sqlite")
    session.unlink(missing_ok=True)
    cfg = OUT / (name + ".cosmic-ray.toml")
    cfg.write_text(
        "[cosmic-ray]\n"
        f"module-path = {json.dumps(module)}\n"
        "timeout = 60\n"
        "excluded-modules = []\n"
        f"test-command = {json.dumps(shlex.join(command))}\n"
        '\n[cosmic-ray.distributor]\nname = "local"\n')
    cosmic_ray = str(Path(sys.executable).parent / "cosmic-ray")
    subprocess.run([cosmic_ray, "init", str(cfg), str(session)],
                   cwd=work, env=env, check=True, capture_output=True)
    with use_db(str(session), WorkDB.Mode.open) as db:
        items = list(db.pending_work_items)
    source = (work / module).read_text()
    spans = annotation_spans(source)
    rows = source.splitlines()
    lists = parameter_lists(source)
    kept = [w for w in items
            if all(PYTHON_OPERATORS.match(m.operator_name)
                   and not in_annotation(m.start_pos, spans)
                   and not is_parameter_marker(rows, m.start_pos, lists)
                   and (lines is None or m.start_pos[0] in lines) for m in w.mutations)]
    # cosmic-ray names its work items by random UUIDs: put them in the module's order first,
    # so that a seed draws the same mutants of the same source on every run
    kept.sort(key=lambda w: [(m.start_pos, m.operator_name, m.occurrence) for m in w.mutations])
    equivalent = [all(is_equivalent(module, m.operator_name, rows[m.start_pos[0] - 1],
                                    lambda m=m: python_mutant_line(source, m))
                      for m in w.mutations) for w in kept]
    return [w for w, eq in zip(kept, equivalent) if not eq], len(kept), sum(equivalent)


_HELD: list = []  # the open lock files of the modules this process runs (held until it exits)


def hold_copies(module: str) -> None:
    """Locks the module's copies of the tree (build/mutation/py/<module>*) for this process: a
    second invocation on the same module, which would copy the tree again under the first one's
    mutants and make them all fail, stops with a message instead."""
    import fcntl

    lock = OUT / "py" / (module.replace("/", "_") + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    fh = open(lock, "w")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.close()
        sys.exit(f"mutation: another run of {module} is using its copies under {lock.parent}; "
                 "wait for it to end")
    _HELD.append(fh)


def run_python(module: str, tests: list[str], sample: int | None, seed: int,
               survivors: list[str], lines: set[int] | None = None,
               jobs: int = 1) -> float | None:
    """Runs the module's mutants (those on ``lines`` only, when given) with ``jobs`` workers
    (tools/mutant_runner.py); its score."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from mutant_runner import run_mutants

    # each module its own copies of the tree, session and configuration: runs of two modules
    # (two invocations) never touch each other's files; two runs of one module are refused
    name = module.replace("/", "_")
    hold_copies(module)
    works = [OUT / "py" / name] + [OUT / "py" / f"{name}.{i}" for i in range(1, jobs)]
    for work in works:
        copy_tree(work)
    env = dict(os.environ, PYTHONPATH="python", PYTHONDONTWRITEBYTECODE="1")
    env.setdefault("ESKIN_BIN_DIR", str(REPO / "build" / "dev"))
    pytest = [*PYTHON, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
              "-p", "no:randomly", *tests]
    # the tests must import the copy that is mutated, or every mutant survives
    where = subprocess.run([*PYTHON, "-c", "import eskin; print(eskin.__file__)"],
                           cwd=works[0], env=env, capture_output=True, text=True).stdout.strip()
    if not Path(where).resolve().is_relative_to(works[0].resolve()):
        sys.exit(f"mutation: the tests would import eskin from {where or '(nowhere)'}, not from "
                 f"the mutated copy under {works[0]}")
    kept, generated, n_equivalent = python_mutants(module, works[0], env, nice() + pytest, lines)
    chosen = choose(kept, sample, seed, module)
    note = "" if lines is None else " (on the changed lines)"
    if not chosen:
        return report(module, 0, 0, generated, note, n_equivalent)
    t0 = time.monotonic()
    base = subprocess.run(nice() + pytest, cwd=works[0], env=env, capture_output=True, text=True)
    if base.returncode != 0:
        sys.exit(f"mutation: the tests of {module} fail unmutated:\n{base.stdout[-3000:]}")
    timeout = 3 * (time.monotonic() - t0) + 30
    source = (works[0] / module).read_text()

    mutants = [(w.mutations[0], w.mutations[0].start_pos[0]) for w in chosen]
    rows = source.splitlines()

    def verdict(i: int, killed: bool | None) -> None:
        m, line = mutants[i]
        if killed is None:
            print(f"  {module}:{line} {m.operator_name}: could not be applied", file=sys.stderr,
                  flush=True)
        elif not killed:
            survivors.append(f"{module}:{line} {m.operator_name} #{m.occurrence}: "
                             f"{rows[line - 1].strip()}")
            print(f"  {survivors[-1]}: survived", file=sys.stderr, flush=True)

    verdicts = run_mutants([(line, lambda m=m: python_mutant_source(source, m))
                            for m, line in mutants], module, works,
                           PYTHON, env, tests, timeout, nice(),
                           progress=module if len(mutants) > 50 else "", verdict=verdict)
    ran = [k for k in verdicts if k is not None]
    return report(module, len(ran), sum(ran), generated, note, n_equivalent)


# --------------------------------------------------------------------------------------- C++

CPP_SWAPS = [(" < ", " <= "), (" <= ", " < "), (" > ", " >= "), (" >= ", " > "),
             (" == ", " != "), (" != ", " == "), (" && ", " || "), (" || ", " && ")]


def strip_strings(line: str) -> str:
    """The line with its string and character literals blanked and its // comment dropped."""
    line = re.sub(r'"(\\.|[^"\\])*"', lambda m: '"' + " " * (len(m.group()) - 2) + '"', line)
    line = re.sub(r"'(\\.|[^'\\])*'", lambda m: "'" + " " * (len(m.group()) - 2) + "'", line)
    cut = line.find("//")
    return line if cut < 0 else line[:cut] + " " * (len(line) - cut)


def cpp_mutants(text: str, mod: CppModule) -> list[tuple[int, str, str]]:
    """(line index, operator, mutated line) for every mutant of the region."""
    lines = text.splitlines()
    start = next((i for i, ln in enumerate(lines) if mod.start in ln), None)
    end = len(lines) if mod.end is None or start is None else next(
        (i for i, ln in enumerate(lines) if mod.end in ln and i > start), None)
    if start is None or end is None:
        sys.exit(f"mutation: {mod.path}: the region's markers {mod.start!r}, {mod.end!r} "
                 "are not in the file (update CPP_MODULES)")
    out: list[tuple[int, str, str]] = []
    # the branches a host build does not compile (#if defined(ESKIN_DEVICE), the controller's
    # build): a mutant there is run by no host test, so none is made
    branches: list[bool] = []  # per open #if: whether its current branch is device-only
    for i, ln in enumerate(lines[:end]):
        d = ln.strip()
        if d.startswith("#if"):
            branches.append(bool(re.match(r"#\s*(if\s+defined\s*\(?\s*|ifdef\s+)ESKIN_DEVICE\b", d)))
        elif d.startswith("#else") and branches:
            branches[-1] = False
        elif d.startswith("#endif") and branches:
            branches.pop()
        if i < start or any(branches):
            continue
        line, code = lines[i], strip_strings(lines[i])
        if code.lstrip().startswith(("#", "/*", "*")):
            continue
        for a, b in CPP_SWAPS:  # comparison and logical operators
            for m in re.finditer(re.escape(a), code):
                out.append((i, f"swap{a.strip()}{b.strip()}",
                            line[: m.start()] + b + line[m.end():]))
        for m in re.finditer(r"(?<![\w.])(\d+)(u|U|ULL|ull|LL)?(?![\w.])", code):  # constants
            v = int(m.group(1))
            out.append((i, "constant+1", line[: m.start(1)] + str(v + 1) + line[m.end(1):]))
        for a, b in (("return true;", "return false;"), ("return false;", "return true;")):
            if a in code:  # returns
                out.append((i, f"return {b.split()[1][:-1]}", line.replace(a, b, 1)))
        m = re.match(r"(\s*)if \((.*)\)(\s*(return|\{|[\w:]+\().*)$", line)
        if m and m.group(2).count("(") == m.group(2).count(")"):  # a deleted check
            out.append((i, "delete check", f"{m.group(1)}if (false && ({m.group(2)})){m.group(3)}"))
    return out


def run_cpp(mod: CppModule, sample: int | None, seed: int, survivors: list[str],
            lines: set[int] | None = None) -> float | None:
    """Runs the file's mutants (those on ``lines`` only, when given); its score. One C++ run
    at a time: the copy and its Debug build (build/mutation/cpp-*) are shared."""
    src = OUT / "cpp-src"
    build = OUT / "cpp-build"
    copy_tree(src)  # file times kept: the build redoes only what changed
    # libstdc++'s assertions: an index past a std::array or std::vector (a loop bound moved by
    # one) aborts the test instead of reading or writing a neighbour unnoticed; AddressSanitizer:
    # so does a read or write past a heap block through a pointer (a check deleted that kept a
    # decoder's reads inside a test's exactly sized buffers)
    flags = "-D_GLIBCXX_ASSERTIONS -fsanitize=address -fno-omit-frame-pointer"
    cache = build / "CMakeCache.txt"
    if not (build / "build.ninja").exists() or flags not in (
            cache.read_text() if cache.exists() else ""):
        cmake = shutil.which("cmake", path=str(Path(sys.executable).parent)) or "cmake"
        subprocess.run([cmake, "-S", str(src), "-B", str(build), "-G", "Ninja",
                        "-DCMAKE_BUILD_TYPE=Debug", "-DESKIN_BUILD_TESTS=ON",
                        "-DESKIN_BUILD_PYTHON=OFF", "-DESKIN_INSTALL=OFF",
                        f"-DCMAKE_CXX_FLAGS={flags}"],
                       check=True, capture_output=True)
    ninja = shutil.which("ninja", path=str(Path(sys.executable).parent)) or "ninja"
    target = src / mod.path
    original = (REPO / mod.path).read_text()
    target.write_text(original)

    def build_and_test(timeout: float | None) -> str:
        b = subprocess.run(nice() + [ninja, "-C", str(build), *mod.targets], capture_output=True)
        if b.returncode != 0:
            return "no-compile"
        for t in mod.targets:
            try:
                r = subprocess.run(nice() + [str(build / t), "--gtest_brief=1"],
                                   capture_output=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                return "timeout"
            if r.returncode != 0:
                return "fail"
        return "pass"

    rows = original.splitlines()
    generated = [m for m in cpp_mutants(original, mod) if lines is None or m[0] + 1 in lines]
    mutants = [m for m in generated
               if not is_equivalent(mod.path, m[1], rows[m[0]], lambda m=m: m[2])]
    n_equivalent = len(generated) - len(mutants)
    chosen = choose(mutants, sample, seed, mod.path)
    note = "" if lines is None else " (on the changed lines)"
    if not chosen:
        return report(mod.path, 0, 0, len(generated), note, n_equivalent)
    t0 = time.monotonic()
    if build_and_test(None) != "pass":
        sys.exit(f"mutation: {', '.join(mod.targets)} fail unmutated")
    timeout = 3 * (time.monotonic() - t0) + 30
    text = original.splitlines(keepends=True)
    n = killed = 0
    try:
        for i, op, new in chosen:
            mutated = text.copy()
            mutated[i] = new + "\n"
            target.write_text("".join(mutated))
            outcome = build_and_test(timeout)
            if outcome == "no-compile":
                continue
            n += 1
            if outcome == "pass":
                survivors.append(f"{mod.path}:{i + 1} {op}: {new.strip()}")
            else:
                killed += 1
            print(f"  {mod.path}:{i + 1} {op}: {'survived' if outcome == 'pass' else outcome}",
                  file=sys.stderr, flush=True)
    finally:
        target.write_text(original)
        # the build back on the original: the next run's copy gives the file its older time
        # again, and ninja would keep the last mutant's objects (its baseline then a mutant)
        subprocess.run(nice() + [ninja, "-C", str(build), *mod.targets], capture_output=True)
    return report(mod.path, n, killed, len(generated), note, n_equivalent)


def modules() -> list[str]:
    """Every module mutation testing covers, Python then C++."""
    return [*PYTHON_MODULES, *(m.path for m in CPP_MODULES)]


def sample_size(text: str) -> int | None:
    if text.strip().lower() in ("", "all"):
        return None
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError("a sample of at least one mutant, or 'all'")
    return n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", default=[],
                    help="only these modules (comma-separated paths; repeatable)")
    ap.add_argument("--sample", type=sample_size, default=None,
                    help="run a random N of each module's mutants ('all' or empty: every one; "
                         "default: all)")
    ap.add_argument("--seed", type=int, default=None,
                    help="the seed of the sample (default: a fresh one, printed)")
    ap.add_argument("--diff", nargs="?", const="", default=None, metavar="REV",
                    help="only the mutants on the lines that differ from REV (default: the "
                         "merge-base with main, or HEAD~1 on main)")
    ap.add_argument("--threshold", type=float, default=0.85)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="mutants of a Python module run side by side (default: one per core)")
    args = ap.parse_args(argv)
    wanted = [m for arg in args.only for m in arg.split(",") if m.strip()]
    wanted = [m.strip() for m in wanted]
    unknown = [m for m in wanted if m not in modules()]
    if unknown:
        print(f"mutation: not a module of tools/mutation.py: {', '.join(unknown)} (the modules: "
              f"{', '.join(modules())})", file=sys.stderr)
        return 2
    seed = args.seed if args.seed is not None else int.from_bytes(os.urandom(4), "big")
    print(f"MUTATION: seed={seed}", flush=True)
    changed: dict[str, set[int]] | None = None
    if args.diff is not None:
        base = args.diff or default_base()
        changed = diff_lines(base)
        print(f"mutation: the lines that differ from {base}", flush=True)
        for path in sorted(changed):
            if path.endswith((".py", ".cpp", ".hpp")) and path.startswith(
                    ("python/eskin/", "cpp/")) and path not in modules():
                print(f"mutation: {path} changed; it is not a module of tools/mutation.py",
                      flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    survivors: list[str] = []
    scores: dict[str, float | None] = {}
    for module in modules():
        if wanted and module not in wanted:
            continue
        lines = None if changed is None else changed.get(module, set())
        if lines is not None and not lines:
            continue
        if module in PYTHON_MODULES:
            scores[module] = run_python(module, PYTHON_MODULES[module], args.sample, seed,
                                        survivors, lines, max(1, args.jobs))
        else:
            mod = next(m for m in CPP_MODULES if m.path == module)
            scores[module] = run_cpp(mod, args.sample, seed, survivors, lines)
    # in the modules' and their lines' order (workers finish in any order)
    survivors.sort(key=lambda s: (s.split(":")[0], int(s.split(":")[1].split()[0])))
    (OUT / "survivors.txt").write_text("".join(s + "\n" for s in survivors))
    print(f"mutation: {len(scores)} modules in {time.monotonic() - t0:.0f} s (seed {seed}); "
          f"{len(survivors)} survivors in {OUT / 'survivors.txt'}")
    return 0 if all(s is None or s >= args.threshold for s in scores.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
