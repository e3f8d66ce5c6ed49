// The multi-patch engine: per-patch detectors, per-model classifiers, skin events.
// A host concern (many links, one host): not part of the device build (mcu/CMakeLists.txt).
#include "eskin/skin.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "raise.hpp"

namespace eskin {

namespace {

constexpr std::int64_t kMaxPatches = std::int64_t{1} << 20;
constexpr std::int64_t kMaxChunk = std::int64_t{1} << 20;

[[noreturn]] void bad(const std::string& field, const std::string& value, const std::string& why) {
  detail::raise<std::invalid_argument>("SkinConfig." + field + " = " + value + ": " + why);
}

// The shared window buffers of SkinConfig::window_buffers and window_chunk_samples: whole
// buffers of the largest window, or as many of its samples cut into chunks.
WindowBufferPool window_pool(const SkinConfig& c, const std::vector<int>& model_of) {
  const auto P = static_cast<std::int64_t>(model_of.size());
  if (c.window_buffers < 0 || c.window_buffers > P)
    bad("window_buffers", std::to_string(c.window_buffers),
        "must be in [0, " + std::to_string(P) + "] (0: one per patch)");
  std::int64_t cap = 0, taxels = 0;
  for (const int m : model_of) {
    const Model& model = *c.models[static_cast<std::size_t>(m)];
    cap = std::max(cap, resolve_window_config(model.window_config(), model.sample_rate_hz()).window_capacity);
    taxels = std::max<std::int64_t>(taxels, std::int64_t{model.rows()} * model.cols());
  }
  const std::int64_t chunk = c.window_chunk_samples;
  if (chunk < 0 || chunk > cap)
    bad("window_chunk_samples", std::to_string(chunk),
        "must be in [0, " + std::to_string(cap) + "] (0: whole window buffers; at most the largest "
        "window_samples)");
  if (chunk > 0 && c.window_buffers == 0)
    bad("window_chunk_samples", std::to_string(chunk), "needs shared window buffers (window_buffers > 0)");
  if (c.window_buffers == 0) return WindowBufferPool();
  if (chunk == 0) return WindowBufferPool(c.window_buffers, cap, taxels);
  const std::int64_t per_window = (cap + chunk - 1) / chunk;
  return WindowBufferPool(c.window_buffers * per_window, chunk, taxels);
}

std::vector<int> patch_models(const SkinConfig& c) {
  if (c.models.empty()) bad("models", "[]", "needs at least one model");
  for (std::size_t i = 0; i < c.models.size(); ++i)
    if (c.models[i] == nullptr) bad("models[" + std::to_string(i) + "]", "null", "must be a loaded model");
  if (c.patch_model.empty()) {
    if (c.n_patches < 1 || c.n_patches > kMaxPatches)
      bad("n_patches", std::to_string(c.n_patches),
          "must be in [1, " + std::to_string(kMaxPatches) + "] when patch_model is empty");
    return std::vector<int>(static_cast<std::size_t>(c.n_patches), 0);
  }
  if (static_cast<std::int64_t>(c.patch_model.size()) > kMaxPatches)
    bad("patch_model", std::to_string(c.patch_model.size()) + " patches",
        "at most " + std::to_string(kMaxPatches));
  for (std::size_t p = 0; p < c.patch_model.size(); ++p) {
    const int m = c.patch_model[p];
    if (m < 0 || static_cast<std::size_t>(m) >= c.models.size())
      bad("patch_model[" + std::to_string(p) + "]", std::to_string(m),
          "must be a model index in [0, " + std::to_string(c.models.size()) + ")");
  }
  return c.patch_model;
}

void check_layout(const SkinConfig& c, std::int64_t total_taxels) {
  if (c.position_dims != 0 && c.position_dims != 2 && c.position_dims != 3)
    bad("position_dims", std::to_string(c.position_dims), "must be 0 (no layout), 2 or 3");
  const auto want = static_cast<std::size_t>(total_taxels * c.position_dims);
  if (c.positions.size() != want)
    bad("positions", std::to_string(c.positions.size()) + " values",
        "must hold " + std::to_string(want) + " (" + std::to_string(total_taxels) + " taxels x " +
            std::to_string(c.position_dims) + " coordinates)");
  for (std::size_t i = 0; i < c.positions.size(); ++i)
    if (!std::isfinite(c.positions[i]))
      bad("positions[" + std::to_string(i) + "]", std::to_string(c.positions[i]), "must be finite");
}

}  // namespace

const char* to_string(SkinStatus s) noexcept {
  switch (s) {
    case SkinStatus::kOk: return "ok";
    case SkinStatus::kBadPatch: return "bad patch";
    case SkinStatus::kNullPointer: return "null pointer";
    case SkinStatus::kBadLength: return "bad length";
  }
  return "unknown";
}

SkinEngine::SkinEngine(const SkinConfig& c) : models_(c.models), position_dims_(c.position_dims) {
  const std::vector<int> model_of = patch_models(c);
  const auto P = static_cast<int>(model_of.size());
  if (c.chunk_samples < 0 || c.chunk_samples > kMaxChunk)
    bad("chunk_samples", std::to_string(c.chunk_samples),
        "must be in [0, " + std::to_string(kMaxChunk) + "] (0: the default)");
  std::int64_t min_frame = kMaxChunk, tensor = 0;
  classifiers_.reserve(models_.size());
  for (const Model* m : models_) {
    classifiers_.emplace_back(*m, Classifier::TensorsOnly{});
    tensor = std::max<std::int64_t>(tensor, std::int64_t{m->rows()} * m->cols() * m->D());
    max_machines_ = std::max(max_machines_, m->machines().size());
    min_frame = std::min(min_frame, resolve_window_config(m->window_config(), m->sample_rate_hz()).frame_len);
  }
  tensor_.assign(static_cast<std::size_t>(tensor), 0.0);
  chunk_ = c.chunk_samples > 0 ? c.chunk_samples : 8 * min_frame;
  window_pool_ = window_pool(c, model_of);
  WindowBufferPool* shared = c.window_buffers > 0 ? &window_pool_ : nullptr;

  patches_.reserve(static_cast<std::size_t>(P));
  for (int p = 0; p < P; ++p) {
    const Model& m = *models_[static_cast<std::size_t>(model_of[static_cast<std::size_t>(p)])];
    const std::int64_t taxels = std::int64_t{m.rows()} * m.cols();
    Patch patch{model_of[static_cast<std::size_t>(p)], total_taxels_, -1,
                TouchDetector(taxels, m.sample_rate_hz(), m.window_config(), SampleStore::kCodes, shared)};
    if (c.position_dims > 0) patch.position_offset = total_taxels_ * c.position_dims;
    patches_.push_back(std::move(patch));
    total_taxels_ += taxels;
  }
  check_layout(c, total_taxels_);
  positions_ = c.positions;

  std::vector<std::int64_t> degree(static_cast<std::size_t>(P) + 1, 0);
  for (std::size_t e = 0; e < c.adjacency.size(); ++e) {
    const auto [a, b] = c.adjacency[e];
    if (a < 0 || a >= P || b < 0 || b >= P || a == b)
      bad("adjacency[" + std::to_string(e) + "]", "(" + std::to_string(a) + ", " + std::to_string(b) + ")",
          "must be two different patches in [0, " + std::to_string(P) + ")");
    ++degree[static_cast<std::size_t>(a) + 1];
    ++degree[static_cast<std::size_t>(b) + 1];
  }
  for (int p = 0; p < P; ++p) degree[static_cast<std::size_t>(p) + 1] += degree[static_cast<std::size_t>(p)];
  adj_offset_ = degree;
  adj_.assign(static_cast<std::size_t>(degree.back()), 0);
  std::vector<std::int64_t> fill(degree.begin(), degree.end() - 1);
  for (const auto& [a, b] : c.adjacency) {
    adj_[static_cast<std::size_t>(fill[static_cast<std::size_t>(a)]++)] = b;
    adj_[static_cast<std::size_t>(fill[static_cast<std::size_t>(b)]++)] = a;
  }

  // a detector ends at most one touch per frame: a chunk of every patch ends at most
  // chunk / frame + 1 touches per patch
  const auto per_patch = static_cast<std::size_t>(chunk_ / min_frame + 1);
  pending_.resize(per_patch * static_cast<std::size_t>(P));
  pending_values_.assign(pending_.size() * max_machines_, 0.0);
}

std::int64_t SkinEngine::patch_taxels(int patch) const noexcept {
  return patches_[static_cast<std::size_t>(patch)].detector.n_taxels();
}
std::int64_t SkinEngine::taxel_offset(int patch) const noexcept {
  return patches_[static_cast<std::size_t>(patch)].taxel_offset;
}
std::int64_t SkinEngine::samples_seen(int patch) const noexcept {
  return patches_[static_cast<std::size_t>(patch)].detector.samples_seen();
}
bool SkinEngine::in_touch(int patch) const noexcept {
  return patches_[static_cast<std::size_t>(patch)].detector.in_touch();
}

std::int64_t SkinEngine::bytes_per_patch() const noexcept {
  const auto P = static_cast<std::int64_t>(patches_.size());
  const auto pending = static_cast<std::int64_t>(pending_.size() * sizeof(Pending) +
                                                 pending_values_.size() * sizeof(double));
  std::int64_t most = 0;
  for (std::size_t p = 0; p < patches_.size(); ++p) {
    const Patch& s = patches_[p];
    const std::int64_t own = static_cast<std::int64_t>(sizeof(Patch) - sizeof(TouchDetector)) +
                             s.detector.memory_bytes() +
                             s.detector.n_taxels() * position_dims_ * std::int64_t{sizeof(double)} +
                             (adj_offset_[p + 1] - adj_offset_[p]) * std::int64_t{sizeof(int)} +
                             std::int64_t{sizeof(std::int64_t)};
    most = std::max(most, own);
  }
  return most + (pending + window_pool_.memory_bytes() + P - 1) / P;
}

bool SkinEngine::decide(int patch, SkinDecision* out) noexcept {
  Patch& p = patches_[static_cast<std::size_t>(patch)];
  const Model& m = *models_[static_cast<std::size_t>(p.model)];
  const TouchDetector& det = p.detector;
  const Status st = det.subsample_last_window(m.D(), m.subsample(), m.short_policy(), tensor_.data());
  if (st != Status::kOk) {
    ++dropped_;
    if (st == Status::kNoWindow) ++unbuffered_;  // no buffer was free at its onset
    return false;
  }
  Decision d;
  if (classifiers_[static_cast<std::size_t>(p.model)].classify_tensor(tensor_.data(), &d) !=
      ClassifyStatus::kOk) {
    ++dropped_;
    return false;
  }
  const TouchWindow& w = det.last_window();
  out->patch = patch;
  out->model = p.model;
  out->label = d.label;
  out->dont_know = d.dont_know;
  out->confidence = d.confidence;
  out->n_machines = d.n_machines;
  out->values = d.values;
  out->window_start = w.start;
  out->window_stop = w.stop;
  out->sample = det.samples_seen();
  out->event = -1;
  position(p, tensor_.data(), m.D(), out);
  return true;
}

void SkinEngine::position(const Patch& p, const double* x, std::int64_t D, SkinDecision* out) const noexcept {
  out->has_position = p.position_offset >= 0;
  out->position = {0.0, 0.0, 0.0};
  if (!out->has_position) return;
  // each taxel's energy over the window's D samples, its mean removed (the ADC offset)
  const std::int64_t K = p.detector.n_taxels();
  const double* pos = positions_.data() + p.position_offset;
  double total = 0.0;
  std::array<double, 3> acc{};
  for (std::int64_t k = 0; k < K; ++k) {
    const double* xk = x + k * D;
    double mean = 0.0;
    for (std::int64_t d = 0; d < D; ++d) mean += xk[d];
    mean /= static_cast<double>(D);
    double e = 0.0;
    for (std::int64_t d = 0; d < D; ++d) e += (xk[d] - mean) * (xk[d] - mean);
    total += e;
    for (int z = 0; z < position_dims_; ++z) acc[static_cast<std::size_t>(z)] += e * pos[k * position_dims_ + z];
  }
  for (int z = 0; z < position_dims_; ++z) {
    double c = 0.0;
    if (total > 0.0) {
      c = acc[static_cast<std::size_t>(z)] / total;
    } else {  // no energy at all: the patch's centre
      for (std::int64_t k = 0; k < K; ++k) c += pos[k * position_dims_ + z];
      c /= static_cast<double>(K);
    }
    out->position[static_cast<std::size_t>(z)] = c;
  }
}

void SkinEngine::record(int patch, SkinSink* sink) noexcept {
  // a detector ends at most one touch per frame, so a chunk's decisions fit (the constructor's
  // bound); delivering early would only change their order
  if (n_pending_ == pending_.size()) deliver(sink);
  Pending& slot = pending_[n_pending_];
  if (!decide(patch, &slot.d)) return;
  slot.values_at = n_pending_ * max_machines_;
  std::copy(slot.d.values, slot.d.values + slot.d.n_machines, pending_values_.data() + slot.values_at);
  ++n_pending_;
}

void SkinEngine::run(int patch, const std::int16_t* samples, std::int64_t n, std::int64_t stride,
                     SkinSink* sink) noexcept {
  TouchDetector& det = patches_[static_cast<std::size_t>(patch)].detector;
  for (std::int64_t i = 0; i < n; ++i)
    if (det.push(samples + i * stride) == Status::kWindow) record(patch, sink);
}

void SkinEngine::assign_event(int patch, SkinDecision* d) noexcept {
  std::int64_t event = -1;
  for (std::int64_t j = adj_offset_[static_cast<std::size_t>(patch)];
       j < adj_offset_[static_cast<std::size_t>(patch) + 1]; ++j) {
    const Patch& q = patches_[static_cast<std::size_t>(adj_[static_cast<std::size_t>(j)])];
    for (const Recent& r : q.recent)
      if (r.event >= 0 && r.start < d->window_stop && d->window_start < r.stop &&
          (event < 0 || r.event < event))
        event = r.event;
  }
  d->event = event >= 0 ? event : next_event_++;
  Patch& p = patches_[static_cast<std::size_t>(patch)];
  p.recent[static_cast<std::size_t>(p.recent_next)] = Recent{d->window_start, d->window_stop, d->event};
  p.recent_next = (p.recent_next + 1) % kRecent;
}

void SkinEngine::deliver(SkinSink* sink) noexcept {
  Pending* first = pending_.data();
  std::sort(first, first + n_pending_, [](const Pending& a, const Pending& b) {
    return a.d.sample != b.d.sample ? a.d.sample < b.d.sample : a.d.patch < b.d.patch;
  });
  for (std::size_t i = 0; i < n_pending_; ++i) {
    SkinDecision& d = pending_[i].d;
    d.values = pending_values_.data() + pending_[i].values_at;
    assign_event(d.patch, &d);
    sink->on_decision(d);
  }
  n_pending_ = 0;
}

SkinStatus SkinEngine::push_block(int patch, const std::int16_t* samples, std::int64_t n,
                                  SkinSink* sink) noexcept {
  if (patch < 0 || patch >= n_patches()) return SkinStatus::kBadPatch;
  if (n < 0) return SkinStatus::kBadLength;
  if (n > 0 && (samples == nullptr || sink == nullptr)) return SkinStatus::kNullPointer;
  const std::int64_t K = patch_taxels(patch);
  for (std::int64_t t = 0; t < n; t += chunk_) {
    run(patch, samples + t * K, std::min(chunk_, n - t), K, sink);
    deliver(sink);
  }
  return SkinStatus::kOk;
}

SkinStatus SkinEngine::push_interleaved(const std::int16_t* block, std::int64_t n,
                                        SkinSink* sink) noexcept {
  if (n < 0) return SkinStatus::kBadLength;
  if (n > 0 && (block == nullptr || sink == nullptr)) return SkinStatus::kNullPointer;
  for (std::int64_t t0 = 0; t0 < n; t0 += chunk_) {
    const std::int64_t m = std::min(chunk_, n - t0);
    const std::int16_t* chunk = block + t0 * total_taxels_;
    for (int p = 0; p < n_patches(); ++p)
      run(p, chunk + patches_[static_cast<std::size_t>(p)].taxel_offset, m, total_taxels_, sink);
    deliver(sink);
  }
  return SkinStatus::kOk;
}

SkinStatus SkinEngine::flush(SkinSink* sink) noexcept {
  if (sink == nullptr) return SkinStatus::kNullPointer;
  for (int p = 0; p < n_patches(); ++p) {
    if (patches_[static_cast<std::size_t>(p)].detector.flush() == Status::kWindow) record(p, sink);
  }
  deliver(sink);
  return SkinStatus::kOk;
}

void SkinEngine::reset() noexcept {
  for (Patch& p : patches_) {
    p.detector.reset();
    p.recent.fill(Recent{});
    p.recent_next = 0;
  }
  n_pending_ = 0;
  next_event_ = 0;
  dropped_ = unbuffered_ = 0;
  window_pool_.reset_counts();
}

}  // namespace eskin
