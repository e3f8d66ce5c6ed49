// The classifier of a loaded model: raw window -> preprocessing -> bases -> machines -> label.
// Everything is allocated in the constructors; the per-decision calls neither allocate nor throw.
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <type_traits>

#include "eskin/model.hpp"
#include "decision_tables.hpp"
#include "model_overlap.hpp"
#if defined(ESKIN_DEVICE)
#include "scalar_bases.hpp"
#endif

namespace eskin {

namespace {
// touches held for the window choice of one recording (Classifier::classify; a controller,
// which classifies a stream touch by touch, keeps a few: the buffer is allocated at construction)
#if defined(ESKIN_DEVICE)
constexpr std::size_t kMaxTouches = 16;
#else
constexpr std::size_t kMaxTouches = 4096;
#endif
// The arithmetic of the distances and of the machines' sums: double on the host; float on a
// controller, whose FPU is single precision (the float32 parity test of `make mcu` bounds the
// difference, docs/mcu.md).
#if defined(ESKIN_DEVICE)
using DecisionReal = float;
#else
using DecisionReal = double;
#endif
// The per-decision tables (distances, energy gaps) are stored in the model's precision: a float32
// model's distances come from float32 bases, so storing them in float loses nothing they carry
// and halves the table (the sums stay in DecisionReal).

// Whether one of two subspaces of R^N (ranks r1, r2 after the cut to alpha) is all of R^N: then
// the projection overlap is exactly the other's rank and the distance r1 + r2 - 2 ov is
// |r1 - r2|, with no product to compute (mode 3 of a 4 x 4 grid at alpha = Q: N = 16 taxels and
// a full-rank time unfolding on both sides, distance 0).
inline bool spans(int r1, int r2, std::size_t N) noexcept {
  return static_cast<std::size_t>(std::max(r1, r2)) == N;
}

}  // namespace

const char* to_string(ClassifyStatus s) noexcept {
  switch (s) {
    case ClassifyStatus::kOk: return "ok";
    case ClassifyStatus::kDecision: return "decision";
    case ClassifyStatus::kBadShape: return "bad_shape";
    case ClassifyStatus::kNoTouch: return "no_touch";
    case ClassifyStatus::kNotFinite: return "not_finite";
    case ClassifyStatus::kTooShort: return "too_short";
    case ClassifyStatus::kKernel: return "kernel_failure";
    case ClassifyStatus::kNullPointer: return "null_pointer";
    case ClassifyStatus::kOverflow: return "too_many_touches";
  }
  return "unknown";
}

const char* overlap_kernel_name() noexcept { return detail::overlap_kernel_name(); }

double log_sigmoid(double z) noexcept {
  // -softplus(-z) = -(max(-z, 0) + log1p(exp(-|z|))): no overflow for any finite z
  return -(std::max(-z, 0.0) + std::log1p(std::exp(-std::fabs(z))));
}

namespace {
// The calibrated rule (format version 4, docs/model-format.md "Decision"), in double on every
// target: l_k = log sigmoid(a_k f_k + b_k) per machine (a binary model: its machine's class
// and the other, l = log sigmoid(+-z)); label = the largest l (the first on ties); confidence
// = its normalised score 1 / sum_k exp(l_k - l_label); "don't know" when below the threshold.
// Two passes over the values, no buffer.
void calibrated_rule(const Model& m, const double* values, Decision* out) noexcept {
  const auto& machines = m.machines();
  int label;
  double sum;
  if (m.rule() == DecisionRule::kBinary) {
    const auto& mm = machines[0];
    const double z = mm.calib_slope * values[0] + mm.calib_offset;
    const double lp = log_sigmoid(z), ln = log_sigmoid(-z);
    label = lp > ln ? mm.positive : mm.negative;
    sum = 1.0 + std::exp(-std::fabs(lp - ln));
  } else {
    std::size_t best = 0;
    double lbest = log_sigmoid(machines[0].calib_slope * values[0] + machines[0].calib_offset);
    for (std::size_t k = 1; k < machines.size(); ++k) {
      const double l = log_sigmoid(machines[k].calib_slope * values[k] + machines[k].calib_offset);
      if (l > lbest) {  // the first of equal scores stays
        best = k;
        lbest = l;
      }
    }
    sum = 0.0;
    for (std::size_t k = 0; k < machines.size(); ++k)
      sum += std::exp(log_sigmoid(machines[k].calib_slope * values[k] + machines[k].calib_offset) -
                      lbest);
    label = machines[best].positive;
  }
  out->label = label;
  out->confidence = 1.0 / sum;
  out->dont_know = out->confidence < m.reject_threshold();
}
}  // namespace

double tensor_log_energy(const double* x, std::size_t n) noexcept {
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i) sum += x[i] * x[i];
  const double mean = n > 0 ? sum / static_cast<double>(n) : 0.0;
  return std::log(mean + model_format::kLogEnergyFloor);  // log(inf) = inf: the factor is 0
}

std::shared_ptr<const detail::DecisionTables> detail::build_decision_tables(const Model& m) {
  // not make_shared: its control block names a type_info, which a -fno-rtti controller build
  // must not reference (tools/mcu_elf_check.py)
  std::shared_ptr<DecisionTables> t(new DecisionTables);
  t->machine_group.resize(m.machines().size());
  auto& groups = t->groups;
  for (std::size_t k = 0; k < m.machines().size(); ++k) {
    const auto& mm = m.machines()[k];
    std::size_t g = 0;
    while (g < groups.size() && groups[g].alpha != mm.alpha) ++g;
    if (g == groups.size()) {
      groups.emplace_back();
      groups.back().alpha = mm.alpha;
    }
    t->machine_group[k] = g;
    auto& svs = groups[g].svs;
    svs.insert(svs.end(), mm.sv_index.begin(), mm.sv_index.end());
  }
  for (auto& g : groups) {
    std::sort(g.svs.begin(), g.svs.end());
    g.svs.erase(std::unique(g.svs.begin(), g.svs.end()), g.svs.end());
    for (int z = 0; z < 3; ++z) {
      const std::size_t N = static_cast<std::size_t>(m.basis_rows(z));
      const std::size_t A = static_cast<std::size_t>(m.alpha_store(z));
      const std::size_t a = static_cast<std::size_t>(g.alpha[static_cast<std::size_t>(z)]);
      const auto zz = static_cast<std::size_t>(z);
      g.proj[zz] = kProjectionCache && N <= 64 && N < a * a;
      if (!g.proj[zz]) continue;
      if (m.is_float64()) g.p64[zz].resize(static_cast<std::size_t>(m.n_support()) * N * N);
      else g.p32[zz].resize(static_cast<std::size_t>(m.n_support()) * N * N);
      for (const std::uint32_t i : g.svs) {
        if (m.is_float64())
          projection(m.bases_f64(z) + i * A * N, N, a, g.p64[zz].data() + i * N * N);
        else
          projection(m.bases_f32(z) + i * A * N, N, a, g.p32[zz].data() + i * N * N);
      }
    }
  }
  return t;
}

// The per-classifier state: the workspace of one decision (the input's bases, projections and
// distances); the model's tables are read through Model::decision_tables().
struct Classifier::Impl {
  // raw: the buffers of Classifier::classify (the raw recording's tensor, the touches of the
  // window choice); a StreamClassifier's classifier only runs classify_tensor.
  Impl(const Model& m, bool raw)
      : layout({static_cast<std::size_t>(m.rows()), static_cast<std::size_t>(m.cols()),
                static_cast<std::size_t>(m.D())},
               {static_cast<std::size_t>(m.alpha_store(0)), static_cast<std::size_t>(m.alpha_store(1)),
                static_cast<std::size_t>(m.alpha_store(2))}),
#if defined(ESKIN_DEVICE)
        ws(layout),
#else
        ws(layout, 1),  // one pattern per decision: no batch of scaled copies
#endif
        tensor(raw ? static_cast<std::size_t>(m.rows()) * m.cols() * m.D() : 0),
        values(m.machines().size()),
        selector(resolve_window_config(m.window_config(), m.sample_rate_hz()),
                 static_cast<std::int64_t>(raw ? kMaxTouches : 1)),
        ov32(detail::select_overlap_f32()),
        ov64(detail::select_overlap_f64()) {
    if (raw)  // the window detector of a raw recording (a tensors-only classifier has none)
      detector.emplace(static_cast<std::int64_t>(m.rows()) * m.cols(), m.sample_rate_hz(),
                       m.window_config(), SampleStore::kNone);
    wide = kWideTables && m.is_float64();
    if (m.is_float64()) xb64.resize(layout.bases_size());
    else xb32.resize(layout.bases_size());
    const detail::DecisionTables& t = m.decision_tables();
    // the input's projection, N x N, for the modes that use projections (largest N of them)
    std::size_t n_proj = 0;
    for (const auto& g : t.groups)
      for (int z = 0; z < 3; ++z)
        if (g.proj[static_cast<std::size_t>(z)]) {
          const auto N = static_cast<std::size_t>(m.basis_rows(z));
          n_proj = std::max(n_proj, N * N);
        }
    // in the model's precision only (a float32 model's projection is rounded from double sums)
    if (m.is_float64()) px.resize(n_proj);
    else px32.resize(n_proj);
    const std::size_t n_dist = t.groups.size() * static_cast<std::size_t>(m.n_support()) * 3;
    const std::size_t n_gap = m.has_amplitude() ? static_cast<std::size_t>(m.n_support()) : 0;
#if !defined(ESKIN_DEVICE)
    ov.resize(static_cast<std::size_t>(m.n_support()));
#endif
    if (wide) {
      dist64.resize(n_dist);
      gap64.resize(n_gap);
    } else {
      dist32.resize(n_dist);
      gap32.resize(n_gap);
    }
  }

  BasisLayout layout;
#if defined(ESKIN_DEVICE)
  detail::ScalarBases<float> ws;  // the controller computes the input's bases in float32
#else
  BasisWorkspace ws;
#endif
  std::optional<TouchDetector> detector;
  std::vector<double> tensor;
  std::vector<double> xb64;
  std::vector<float> xb32;
  int xr[3] = {0, 0, 0};
  std::vector<double> px;    // the input's projection (N x N) of the current mode
  std::vector<float> px32;
  // (group, sv, mode) squared mode distances and (e(x) - e(sv_i))^2 per support vector (the
  // amplitude factor): double for a float64 model on the host, float otherwise
#if defined(ESKIN_DEVICE)
  static constexpr bool kWideTables = false;
#else
  static constexpr bool kWideTables = true;
#endif
  bool wide = false;
  std::vector<double> dist64, gap64;
  std::vector<float> dist32, gap32;
  void set_dist(std::size_t i, DecisionReal v) noexcept {
    if (wide) dist64[i] = static_cast<double>(v);
    else dist32[i] = static_cast<float>(v);
  }
  void set_gap(std::size_t i, DecisionReal v) noexcept {
    if (wide) gap64[i] = static_cast<double>(v);
    else gap32[i] = static_cast<float>(v);
  }
  std::vector<double> values;
  // The window choice of eskin::detect_window (WindowConfig.select), the same code as the
  // batch preprocessing; its buffer (kMaxTouches) is allocated here, never per decision.
  WindowSelector selector;
  detail::OverlapF32 ov32;
  detail::OverlapF64 ov64;
  detail::DotF32 dot32 = detail::select_dot_f32();
  detail::DotF64 dot64 = detail::select_dot_f64();
#if !defined(ESKIN_DEVICE)
  detail::OverlapsF32 ovs32 = detail::select_overlaps_f32();
  std::vector<double> ov;  // the overlaps of one mode, per support vector of a group
#endif
};

namespace {
// f(x) of one machine from the squared mode distances `d` of its group (sv, mode) and, for a
// machine with an amplitude factor, the squared log-energy gaps (sv).
template <typename Stored>
double machine_value(const ModelMachine& mm, const Stored* d, const Stored* gap) noexcept {
  DecisionReal w[3];
  for (int z = 0; z < 3; ++z)
    w[z] = static_cast<DecisionReal>(1.0 / (2.0 * mm.sigma[static_cast<std::size_t>(z)] *
                                            mm.sigma[static_cast<std::size_t>(z)]));
  DecisionReal f = 0;
  if (mm.amplitude_width > 0) {
    // widths in [1e-6, 1e6] and |e_i| <= 1e4 (the loader's checks): wa and every finite gap
    // times wa are finite; an infinite gap (mean square overflowed) gives exp(-inf) = 0
    const auto wa = static_cast<DecisionReal>(1.0 / (2.0 * mm.amplitude_width * mm.amplitude_width));
    for (std::size_t t = 0; t < mm.sv_index.size(); ++t) {
      const std::size_t i = mm.sv_index[t];
      const Stored* di = d + i * 3;
      f += static_cast<DecisionReal>(mm.coef[t]) *
           std::exp(-(static_cast<DecisionReal>(di[0]) * w[0] +
                      static_cast<DecisionReal>(di[1]) * w[1] +
                      static_cast<DecisionReal>(di[2]) * w[2] + static_cast<DecisionReal>(gap[i]) * wa));
    }
  } else {
    for (std::size_t t = 0; t < mm.sv_index.size(); ++t) {
      const Stored* di = d + static_cast<std::size_t>(mm.sv_index[t]) * 3;
      f += static_cast<DecisionReal>(mm.coef[t]) *
           std::exp(-(static_cast<DecisionReal>(di[0]) * w[0] +
                      static_cast<DecisionReal>(di[1]) * w[1] + static_cast<DecisionReal>(di[2]) * w[2]));
    }
  }
  return static_cast<double>(f) + mm.intercept;
}
}  // namespace

Classifier::Classifier(const Model& model)
    : model_(&model), impl_(std::make_unique<Impl>(model, /*raw=*/true)) {}
Classifier::Classifier(const Model& model, TensorsOnly)
    : model_(&model), impl_(std::make_unique<Impl>(model, /*raw=*/false)) {}
Classifier::~Classifier() = default;
Classifier::Classifier(Classifier&&) noexcept = default;

namespace {
// The squared distances of mode z between the input (its bases in s) and every support vector
// of group g, into s's table: |r_i - r_x| where one of the two subspaces is all of R^N, else
// r_i + r_x - 2 ov from the projections or the overlap of the bases. A float32 model's mode
// without either (alpha < N: no subspace spans R^N) takes the overlaps of all the group's
// support vectors in one call on the host (detail::OverlapsF32).
void mode_distances(const Model& m, Classifier::Impl& s, std::size_t g, int z) noexcept {
  const detail::DecisionTables& tables = m.decision_tables();
  const std::size_t n_sv = static_cast<std::size_t>(m.n_support());
  const bool f64 = m.is_float64();
  const auto& grp = tables.groups[g];
  const std::size_t N = static_cast<std::size_t>(m.basis_rows(z));
  const std::size_t A = static_cast<std::size_t>(m.alpha_store(z));
  const std::size_t a = static_cast<std::size_t>(grp.alpha[static_cast<std::size_t>(z)]);
  const int rx = std::min(s.xr[z], static_cast<int>(a));
  const std::size_t xoff = s.layout.offset(static_cast<std::size_t>(z));
  const auto zz = static_cast<std::size_t>(z);
  const bool proj = grp.proj[zz];
  if (proj) {
    if (f64) detail::projection(s.xb64.data() + xoff, N, a, s.px.data());
    else detail::projection(s.xb32.data() + xoff, N, a, s.px32.data());
  }
#if !defined(ESKIN_DEVICE)
  if (!proj && !f64 && a < N) {
    s.ovs32(m.bases_f32(z), A * N, grp.svs.data(), grp.svs.size(), s.xb32.data() + xoff, N, a,
            s.ov.data());
    for (std::size_t t = 0; t < grp.svs.size(); ++t) {
      const std::uint32_t i = grp.svs[t];
      const int ri = std::min(m.rank(static_cast<int>(i), z), static_cast<int>(a));
      s.set_dist((g * n_sv + i) * 3 + zz,
                 std::max(DecisionReal(0), static_cast<DecisionReal>(ri) +
                                               static_cast<DecisionReal>(rx) -
                                               DecisionReal(2) * static_cast<DecisionReal>(s.ov[t])));
    }
    return;
  }
#endif
  for (const std::uint32_t i : grp.svs) {
    const std::size_t at = (g * n_sv + i) * 3 + zz;
    const int ri = std::min(m.rank(static_cast<int>(i), z), static_cast<int>(a));
    if (spans(ri, rx, N)) {
      s.set_dist(at, static_cast<DecisionReal>(std::abs(ri - rx)));
    } else if (proj) {  // <P_sv, P_x>_F, summed in double
      const double ov = f64 ? s.dot64(grp.p64[zz].data() + i * N * N, s.px.data(), N * N)
                            : s.dot32(grp.p32[zz].data() + i * N * N, s.px32.data(), N * N);
      s.set_dist(at, static_cast<DecisionReal>(
          std::max(0.0, static_cast<double>(ri) + static_cast<double>(rx) - 2.0 * ov)));
    } else {
      const auto ov = static_cast<DecisionReal>(
          f64 ? s.ov64(m.bases_f64(z) + i * A * N, s.xb64.data() + xoff, N, a)
              : s.ov32(m.bases_f32(z) + i * A * N, s.xb32.data() + xoff, N, a));
      s.set_dist(at, std::max(DecisionReal(0), static_cast<DecisionReal>(ri) +
                                                   static_cast<DecisionReal>(rx) -
                                                   DecisionReal(2) * ov));
    }
  }
}
}  // namespace

ClassifyStatus Classifier::classify_tensor(const double* tensor, Decision* out) noexcept {
  if (tensor == nullptr || out == nullptr) return ClassifyStatus::kNullPointer;
  const Model& m = *model_;
  Impl& s = *impl_;
  const bool f64 = m.is_float64();
  const KernelStatus ks = f64 ? s.ws.compute(tensor, s.xb64.data(), s.xr)
                              : s.ws.compute(tensor, s.xb32.data(), s.xr);
  if (ks == KernelStatus::not_finite) return ClassifyStatus::kNotFinite;
  if (ks != KernelStatus::ok) return ClassifyStatus::kKernel;

  const std::size_t n_sv = static_cast<std::size_t>(m.n_support());
  const detail::DecisionTables& tables = m.decision_tables();
  for (std::size_t g = 0; g < tables.groups.size(); ++g)
    for (int z = 0; z < 3; ++z) mode_distances(m, s, g, z);
  if (m.has_amplitude()) {
    // the amplitude factor's input: e(x) once per decision, in double (also on a controller)
    const double ex = tensor_log_energy(tensor, static_cast<std::size_t>(m.rows()) * m.cols() * m.D());
    const auto& e = m.sv_log_energy();
    for (std::size_t i = 0; i < n_sv; ++i)
      s.set_gap(i, static_cast<DecisionReal>((ex - e[i]) * (ex - e[i])));  // inf if ex is
  }
  const auto& machines = m.machines();
  for (std::size_t k = 0; k < machines.size(); ++k)
    s.values[k] = s.wide ? machine_value(machines[k], s.dist64.data() + tables.machine_group[k] * n_sv * 3,
                                         s.gap64.data())
                         : machine_value(machines[k], s.dist32.data() + tables.machine_group[k] * n_sv * 3,
                                         s.gap32.data());
  out->n_machines = static_cast<int>(machines.size());
  out->values = s.values.data();
  if (m.calibrated()) {
    calibrated_rule(m, s.values.data(), out);
  } else if (m.rule() == DecisionRule::kBinary) {
    const auto& mm = machines[0];
    out->label = s.values[0] > 0 ? mm.positive : mm.negative;
    out->dont_know = false;
    out->confidence = std::numeric_limits<double>::quiet_NaN();
  } else {
    // Paper rule: exactly one machine claims (f > 0) -> that class; otherwise the largest f,
    // flagged as "don't know" (no claim, or several).
    int claims = 0, claimed = -1;
    std::size_t best = 0;
    for (std::size_t k = 0; k < machines.size(); ++k) {
      if (s.values[k] > 0) {
        ++claims;
        claimed = static_cast<int>(k);
      }
      if (s.values[k] > s.values[best]) best = k;
    }
    if (claims == 1) {
      out->label = machines[static_cast<std::size_t>(claimed)].positive;
      out->dont_know = false;
    } else {
      out->label = machines[best].positive;
      out->dont_know = true;
    }
    out->confidence = std::numeric_limits<double>::quiet_NaN();
  }
  return ClassifyStatus::kOk;
}

template <typename T>
ClassifyStatus Classifier::classify_raw(const T* x, int rows, int cols, std::int64_t T_total,
                                        std::int64_t length, Decision* out) noexcept {
  if (x == nullptr || out == nullptr) return ClassifyStatus::kNullPointer;
  const Model& m = *model_;
  Impl& s = *impl_;
  if (rows != m.rows() || cols != m.cols() || T_total < 1 || length < 1 || length > T_total ||
      s.tensor.empty())
    return ClassifyStatus::kBadShape;
  const std::int64_t n_taxels = static_cast<std::int64_t>(rows) * cols;
  TouchWindow w;
  w.start = 0;
  w.stop = length;
  w.found = true;
  if (m.window_mode() == WindowMode::kEnergy) {
    TouchDetector& det = *s.detector;
    det.reset();
    WindowSelector& sel = s.selector;
    sel.reset();
    for (std::int64_t t = 0; t < length; ++t) {
      const Status st = det.push_strided(x + t, T_total);
      if (st == Status::kWindow) {
        sel.add(det.last_window());
      } else if (st == Status::kNonFiniteSample) {
        return ClassifyStatus::kNotFinite;
      }
    }
    if (det.flush() == Status::kWindow) sel.add(det.last_window());
    if (!sel.empty()) {
      w = sel.result();
    } else {
      if (det.params().fallback == 1) return ClassifyStatus::kNoTouch;
      w.found = false;
    }
  } else if constexpr (std::is_floating_point_v<T>) {
    for (std::int64_t k = 0; k < n_taxels; ++k)
      for (std::int64_t t = 0; t < length; ++t)
        if (!std::isfinite(x[k * T_total + t])) return ClassifyStatus::kNotFinite;
  }
  const Status st = subsample_window(x + w.start, n_taxels, T_total, w.stride, w.stop - w.start,
                                     m.D(), m.subsample(), m.short_policy(), s.tensor.data(),
                                     w.stride);
  if (st != Status::kOk) return ClassifyStatus::kTooShort;
  const ClassifyStatus cs = classify_tensor(s.tensor.data(), out);
  out->window_start = w.start;
  out->window_stop = w.stop;
  out->window_found = w.found;
  return cs;
}

ClassifyStatus Classifier::classify(const std::int16_t* x, int rows, int cols, std::int64_t T,
                                    std::int64_t length, Decision* out) noexcept {
  return classify_raw(x, rows, cols, T, length, out);
}
ClassifyStatus Classifier::classify(const float* x, int rows, int cols, std::int64_t T,
                                    std::int64_t length, Decision* out) noexcept {
  return classify_raw(x, rows, cols, T, length, out);
}
ClassifyStatus Classifier::classify(const double* x, int rows, int cols, std::int64_t T,
                                    std::int64_t length, Decision* out) noexcept {
  return classify_raw(x, rows, cols, T, length, out);
}

// ---- streaming

StreamClassifier::StreamClassifier(const Model& model)
    : model_(&model),
      classifier_(model, Classifier::TensorsOnly{}),
      detector_(static_cast<std::int64_t>(model.rows()) * model.cols(), model.sample_rate_hz(),
                model.window_config(), /*store_samples=*/true),
      tensor_(static_cast<std::size_t>(model.rows()) * model.cols() * model.D()) {}

ClassifyStatus StreamClassifier::after_push(Status st) noexcept {
  switch (st) {
    case Status::kOk: return ClassifyStatus::kOk;
    case Status::kNonFiniteSample: return ClassifyStatus::kNotFinite;
    case Status::kNullPointer: return ClassifyStatus::kNullPointer;
    case Status::kWindow: break;
    default: return ClassifyStatus::kBadShape;
  }
  const TouchWindow& w = detector_.last_window();
  const Status ss = detector_.subsample_last_window(model_->D(), model_->subsample(),
                                                    model_->short_policy(), tensor_.data());
  if (ss != Status::kOk) return ClassifyStatus::kTooShort;
  const ClassifyStatus cs = classifier_.classify_tensor(tensor_.data(), &decision_);
  if (cs != ClassifyStatus::kOk) return cs;
  decision_.window_start = w.start;
  decision_.window_stop = w.stop;
  decision_.window_found = true;
  return ClassifyStatus::kDecision;
}

ClassifyStatus StreamClassifier::push(const std::int16_t* sample) noexcept {
  return after_push(detector_.push(sample));
}
ClassifyStatus StreamClassifier::push(const float* sample) noexcept {
  return after_push(detector_.push(sample));
}
ClassifyStatus StreamClassifier::push(const double* sample) noexcept {
  return after_push(detector_.push(sample));
}
ClassifyStatus StreamClassifier::flush() noexcept { return after_push(detector_.flush()); }
void StreamClassifier::reset() noexcept {
  detector_.reset();
  decision_ = Decision{};
}

}  // namespace eskin
