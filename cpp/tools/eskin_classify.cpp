// eskin-classify MODEL [FILE|-]: classify recordings with a .eskin model, one line per recording.
//
// Input (a file, or standard input when FILE is "-" or absent), recognised by its first bytes:
//  * .npy (NumPy format 1.0/2.0/3.0), C order, dtype <i2, <f4 or <f8, shape (rows, cols, T) for
//    one recording or (n, rows, cols, T) for n recordings;
//  * raw records (docs/model-format.md, "Raw recordings"): any number of records, each a 16-byte
//    header  "ESKR" | u16 rows | u16 cols | u32 T | u32 reserved = 0  (little-endian)
//    followed by rows*cols*T int16 little-endian samples in C order (rows, cols, T), i.e. taxel by
//    taxel, the layout of a campaign file's /recordings/signals.
//
// Output: a '#' comment line describing the model, a header line, then per recording the
// tab-separated fields  index, label, dont_know (0/1), window_start, window_stop, and one
// decision value per machine (%.17g). A recording that cannot be classified prints its status
// as the label ("error:<status>").
//
// A file eskin knows given in the wrong place (a replay file, a campaign, a Python model, a
// .eskin model as FILE, recordings as MODEL) is named, with the tool or command that reads it.
//
// Exit status: 0 all recordings classified, 1 some could not be, 2 bad usage, model or input.
#include <sys/stat.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "eskin/model.hpp"
#include "eskin/npy.hpp"
#include "eskin/version.hpp"

namespace {

struct InputError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

const char* kUsage =
    "usage: eskin-classify MODEL [FILE|-]\n"
    "       eskin-classify --version\n"
    "  Classify the recordings in FILE (or standard input) with the .eskin model MODEL.\n"
    "  FILE: .npy int16/float32/float64 of shape (rows, cols, T) or (n, rows, cols, T), or raw\n"
    "  records ('ESKR' u16 rows u16 cols u32 T u32 0, then rows*cols*T int16, little-endian).\n"
    "  Prints one tab-separated line per recording: index, label, dont_know, window_start,\n"
    "  window_stop, and the decision value of each machine.\n";

// Reads up to `count` elements, growing `out` as the bytes arrive: a size declared by the input
// never allocates more than the input really holds. Returns the number of whole elements read.
template <typename T>
std::size_t read_elements(std::istream& in, std::size_t count, std::vector<T>& out) {
  constexpr std::size_t kChunk = (std::size_t{1} << 20) / sizeof(T);
  out.clear();
  while (out.size() < count) {
    const std::size_t old = out.size(), want = std::min(kChunk, count - old);
    out.resize(old + want);
    in.read(reinterpret_cast<char*>(out.data() + old), static_cast<std::streamsize>(want * sizeof(T)));
    const std::size_t got = static_cast<std::size_t>(in.gcount()) / sizeof(T);
    if (got < want) {
      out.resize(old + got);
      break;
    }
  }
  return out.size();
}

// Size of a regular file, or -1 (a pipe, a terminal, a device).
std::int64_t regular_file_size(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return -1;
  return static_cast<std::int64_t>(st.st_size);
}

class Printer {
 public:
  explicit Printer(const eskin::Model& m) : model_(m), clf_(m) {}

  void header(const std::string& model_path) const {
    const auto& names = model_.class_names();
    std::printf("# model %s: %zu classes (", model_path.c_str(), names.size());
    for (std::size_t i = 0; i < names.size(); ++i) std::printf("%s%s", i ? " " : "", names[i].c_str());
    int with_factor = 0;
    for (const auto& mm : model_.machines()) with_factor += mm.amplitude_width > 0 ? 1 : 0;
    std::printf("), rule %s, grid %dx%d, D=%d, %s, %d support vectors, amplitude factor on %d of "
                "%zu machines\n",
                model_.rule() == eskin::DecisionRule::kBinary ? "binary" : "one_vs_all",
                model_.rows(), model_.cols(), model_.D(), model_.is_float64() ? "float64" : "float32",
                model_.n_support(), with_factor, model_.machines().size());
    std::printf("index\tlabel\tdont_know\twindow_start\twindow_stop");
    for (const auto& mm : model_.machines()) {
      if (model_.rule() == eskin::DecisionRule::kBinary)
        std::printf("\tf_%s_vs_%s", names[static_cast<std::size_t>(mm.positive)].c_str(),
                    names[static_cast<std::size_t>(mm.negative)].c_str());
      else
        std::printf("\tf_%s", names[static_cast<std::size_t>(mm.positive)].c_str());
    }
    std::printf("\n");
  }

  template <typename T>
  void classify(const T* x, int rows, int cols, std::int64_t T_total) {
    eskin::Decision d;
    const eskin::ClassifyStatus s = clf_.classify(x, rows, cols, T_total, T_total, &d);
    if (s != eskin::ClassifyStatus::kOk) {
      ++failed_;
      std::printf("%ld\terror:%s\t-\t-\t-", index_++, eskin::to_string(s));
      for (std::size_t k = 0; k < model_.machines().size(); ++k) std::printf("\tnan");
      std::printf("\n");
      return;
    }
    std::printf("%ld\t%s\t%d\t%lld\t%lld", index_++,
                model_.class_names()[static_cast<std::size_t>(d.label)].c_str(), d.dont_know ? 1 : 0,
                static_cast<long long>(d.window_start), static_cast<long long>(d.window_stop));
    for (int k = 0; k < d.n_machines; ++k) std::printf("\t%.17g", d.values[k]);
    std::printf("\n");
  }

  long failed() const { return failed_; }
  long count() const { return index_; }

 private:
  const eskin::Model& model_;
  eskin::Classifier clf_;
  long index_ = 0;
  long failed_ = 0;
};

std::uint32_t le32(const std::uint8_t* p) {
  return std::uint32_t{p[0]} | (std::uint32_t{p[1]} << 8) | (std::uint32_t{p[2]} << 16) |
         (std::uint32_t{p[3]} << 24);
}
std::uint16_t le16(const std::uint8_t* p) {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}

template <typename Item>
void classify_recordings(std::istream& in, const eskin::NpyHeader& h, std::int64_t n, int rows,
                         int cols, std::int64_t T, const std::string& what, Printer& pr) {
  const std::size_t per = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols) *
                          static_cast<std::size_t>(T);
  std::vector<Item> x;
  for (std::int64_t i = 0; i < n; ++i) {
    if (read_elements(in, per, x) != per)  // only reached on a pipe: a file's size was checked
      throw InputError(what + ": .npy data truncated in recording " + std::to_string(i) +
                       " (shape " + eskin::npy_shape_string(h.shape) + ")");
    pr.classify(x.data(), rows, cols, T);  // little-endian host (x86, ARM)
  }
}

// ---- .npy (eskin/npy.hpp): the header is checked, and a file's size against it, before any
// data is read; recordings are then read and classified one at a time.
void classify_npy(std::istream& in, const std::uint8_t* first, std::size_t n_first,
                  std::int64_t file_bytes, const std::string& what, Printer& pr,
                  const eskin::Model& m) {
  std::vector<std::uint8_t> head(first, first + n_first), more;
  read_elements(in, eskin::kNpyPreambleBytes - head.size(), more);
  head.insert(head.end(), more.begin(), more.end());
  const std::size_t data_offset = eskin::npy_data_offset(head.data(), head.size(), what);
  if (data_offset > head.size()) {
    read_elements(in, data_offset - head.size(), more);
    head.insert(head.end(), more.begin(), more.end());
  }
  const eskin::NpyHeader h = eskin::parse_npy_header(head.data(), head.size(), what);
  if (file_bytes >= 0) eskin::check_npy_file_size(h, static_cast<std::uint64_t>(file_bytes), what);
  const auto& shape = h.shape;
  if (shape.size() != 3 && shape.size() != 4)
    throw InputError(what + ": .npy shape " + eskin::npy_shape_string(shape) +
                     ", expected (rows, cols, T) or (n, rows, cols, T)");
  const std::size_t k = shape.size() - 3;
  const std::uint64_t n = k ? shape[0] : 1, rows = shape[k], cols = shape[k + 1], T = shape[k + 2];
  if (rows != static_cast<std::uint64_t>(m.rows()) || cols != static_cast<std::uint64_t>(m.cols()))
    throw InputError(what + ": recordings are " + std::to_string(rows) + "x" + std::to_string(cols) +
                     " taxels, the model expects " + std::to_string(m.rows()) + "x" + std::to_string(m.cols()));
  if (T < 1) throw InputError(what + ": recordings have no samples (T = 0)");
  // shape entries are bounded by the header check (n * rows * cols * T * item <= 1 TiB)
  const auto ni = static_cast<std::int64_t>(n), Ti = static_cast<std::int64_t>(T);
  switch (h.dtype) {
    case eskin::NpyDtype::kInt16:
      classify_recordings<std::int16_t>(in, h, ni, m.rows(), m.cols(), Ti, what, pr);
      break;
    case eskin::NpyDtype::kFloat32:
      classify_recordings<float>(in, h, ni, m.rows(), m.cols(), Ti, what, pr);
      break;
    case eskin::NpyDtype::kFloat64:
      classify_recordings<double>(in, h, ni, m.rows(), m.cols(), Ti, what, pr);
      break;
  }
  if (file_bytes < 0 && in.peek() != std::char_traits<char>::eof())
    throw InputError(what + ": unexpected bytes after the .npy data (shape " +
                     eskin::npy_shape_string(shape) + ")");
}

// ---- raw records, read one at a time (works on an endless pipe)
void classify_raw(std::istream& in, const std::uint8_t* first, std::size_t n_first,
                  const std::string& what, Printer& pr, const eskin::Model& m) {
  std::vector<std::uint8_t> hdr(first, first + n_first);
  std::vector<std::int16_t> data;
  long record = 0;
  for (;;) {
    while (hdr.size() < 16) {
      const int c = in.get();
      if (c == EOF) break;
      hdr.push_back(static_cast<std::uint8_t>(c));
    }
    if (hdr.empty()) return;  // clean end
    const std::string rec = what + ": record " + std::to_string(record);
    if (hdr.size() < 16) throw InputError(rec + ": truncated header");
    if (std::memcmp(hdr.data(), "ESKR", 4) != 0) throw InputError(rec + ": bad magic (expected 'ESKR')");
    const int rows = le16(&hdr[4]), cols = le16(&hdr[6]);
    const std::uint32_t T = le32(&hdr[8]);
    if (le32(&hdr[12]) != 0) throw InputError(rec + ": reserved header field is not 0");
    if (rows != m.rows() || cols != m.cols())
      throw InputError(rec + ": " + std::to_string(rows) + "x" + std::to_string(cols) +
                       " taxels, the model expects " + std::to_string(m.rows()) + "x" + std::to_string(m.cols()));
    if (T < 1 || T > (1u << 28)) throw InputError(rec + ": T = " + std::to_string(T) + " out of range");
    const std::size_t count = static_cast<std::size_t>(rows) * cols * T;
    const std::size_t got = read_elements(in, count, data);  // grows only as samples arrive
    if (got != count)
      throw InputError(rec + ": truncated samples (" + std::to_string(got * 2) + " of " +
                       std::to_string(count * 2) + " bytes)");
    pr.classify(data.data(), rows, cols, static_cast<std::int64_t>(T));
    std::fflush(stdout);
    hdr.clear();
    ++record;
  }
}

// ---- what a file given in the wrong place is, and the tool that reads it. The raw-record magic
// "ESKR" is a prefix of the replay magic "ESKREPLY", so the longer magic is checked first.
struct KnownFile {
  const char* magic;
  std::size_t size;
  const char* what;    // "an eskin replay file (.eskr)"
  const char* reader;  // the tool that reads it
};
const KnownFile kKnownFiles[] = {
    {"\x89" "ESKIN\r\n", 8, "an eskin model (.eskin)",
     "eskin-classify reads it as MODEL, its first argument"},
    {"ESKREPLY", 8, "an eskin replay file (.eskr, the stream eskin-fw-sim plays)",
     "eskin-fw-sim streams it; `eskin replay CAMPAIGN -o recordings.npy` writes recordings for "
     "eskin-classify"},
    {"\x89HDF\r\n\x1a\n", 8, "an HDF5 file (an eskin campaign?)",
     "`eskin replay CAMPAIGN -o recordings.npy` writes a campaign's recordings for "
     "eskin-classify"},
    {"\x93NUMPY", 6, "a .npy array (recordings)", "eskin-classify reads it as FILE, after MODEL"},
    {"ESKR", 4, "raw 'ESKR' records (recordings)", "eskin-classify reads them as FILE, after MODEL"},
    // eskin train's joblib files: zlib-compressed (levels 1-9), or plain pickles (protocols 2-5)
#define ESKIN_JOBLIB(m)                                                              \
  {m, 2, "a Python model file (joblib; eskin train writes them)",                   \
   "`eskin export MODEL.joblib -o MODEL.eskin` writes the .eskin model eskin-classify " \
   "reads"}
    ESKIN_JOBLIB("\x78\x01"), ESKIN_JOBLIB("\x78\x5e"), ESKIN_JOBLIB("\x78\x9c"),
    ESKIN_JOBLIB("\x78\xda"), ESKIN_JOBLIB("\x80\x02"), ESKIN_JOBLIB("\x80\x03"),
    ESKIN_JOBLIB("\x80\x04"), ESKIN_JOBLIB("\x80\x05"),
#undef ESKIN_JOBLIB
};

// The known file these first bytes start, or nullptr.
const KnownFile* known_file(const std::uint8_t* head, std::size_t n) {
  for (const auto& k : kKnownFiles)
    if (n >= k.size && std::memcmp(head, k.magic, k.size) == 0) return &k;
  return nullptr;
}

// The first bytes of a regular file (fewer when it is shorter or cannot be read).
std::size_t file_head(const std::string& path, std::uint8_t* out, std::size_t n) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return 0;
  f.read(reinterpret_cast<char*>(out), static_cast<std::streamsize>(n));
  return static_cast<std::size_t>(f.gcount());
}

// MODEL must be a .eskin file: anything else eskin knows is named with the tool that reads it.
void check_model_path(const std::string& path) {
  std::uint8_t head[8];
  const std::size_t n = file_head(path, head, sizeof head);
  const KnownFile* k = known_file(head, n);
  if (k == nullptr || k == &kKnownFiles[0]) return;  // a model, or unknown: the loader says
  throw InputError("MODEL " + path + ": " + k->what + ", not a .eskin model; " + k->reader +
                   " (usage: eskin-classify MODEL.eskin [FILE|-])");
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (!args.empty() && (args[0] == "-h" || args[0] == "--help")) {
    std::fputs(kUsage, stdout);
    return 0;
  }
  if (!args.empty() && args[0] == "--version") {
    std::printf("eskin-classify %s\n", eskin::kVersion);
    return 0;
  }
  for (const auto& a : args) {
    if (a.size() > 1 && a[0] == '-') {
      std::fprintf(stderr, "eskin-classify: unknown option %s\n%s", a.c_str(), kUsage);
      return 2;
    }
  }
  if (args.empty() || args.size() > 2) {
    std::fputs(kUsage, stderr);
    return 2;
  }
  const std::string model_path = args[0];
  const std::string input = args.size() == 2 ? args[1] : "-";
  try {
    check_model_path(model_path);
    const eskin::Model model = eskin::Model::load(model_path);
    Printer pr(model);
    std::ifstream file;
    std::istream* in = &std::cin;
    std::string what = "<stdin>";
    std::int64_t file_bytes = -1;
    if (input != "-") {
      file.open(input, std::ios::binary);
      if (!file) throw InputError(input + ": cannot open");
      in = &file;
      what = input;
      file_bytes = regular_file_size(input);
    }
    std::uint8_t magic[8];
    in->read(reinterpret_cast<char*>(magic), 8);
    const std::size_t got = static_cast<std::size_t>(in->gcount());
    const KnownFile* known = known_file(magic, got);
    if (got >= 6 && eskin::is_npy(magic, got)) {
      pr.header(model_path);
      classify_npy(*in, magic, got, file_bytes, what, pr, model);
    } else if (got == 0) {
      throw InputError(what + ": empty input");
    } else if (known != nullptr && std::strcmp(known->magic, "ESKR") == 0) {
      pr.header(model_path);
      classify_raw(*in, magic, got, what, pr, model);
    } else if (known != nullptr) {
      throw InputError(what + ": " + known->what + ", not recordings: " + known->reader);
    } else {
      throw InputError(what + ": neither a .npy file nor raw 'ESKR' records (`eskin replay "
                              "CAMPAIGN -o FILE.npy`, or `--format records`, writes them)");
    }
    std::fflush(stdout);
    return pr.failed() > 0 ? 1 : 0;
  } catch (const eskin::ModelFormatError& e) {
    std::fflush(stdout);
    std::fprintf(stderr, "eskin-classify: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fflush(stdout);
    std::fprintf(stderr, "eskin-classify: %s\n", e.what());
    return 2;
  }
}
