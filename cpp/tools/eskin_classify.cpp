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
// Exit status: 0 all recordings classified, 1 some could not be, 2 bad usage, model or input.
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

std::vector<std::uint8_t> read_all(std::istream& in) {
  std::vector<std::uint8_t> out;
  std::vector<char> chunk(1 << 16);
  while (in) {
    in.read(chunk.data(), static_cast<std::streamsize>(chunk.size()));
    out.insert(out.end(), chunk.begin(), chunk.begin() + in.gcount());
  }
  return out;
}

class Printer {
 public:
  explicit Printer(const eskin::Model& m) : model_(m), clf_(m) {}

  void header(const std::string& model_path) const {
    const auto& names = model_.class_names();
    std::printf("# model %s: %zu classes (", model_path.c_str(), names.size());
    for (std::size_t i = 0; i < names.size(); ++i) std::printf("%s%s", i ? " " : "", names[i].c_str());
    std::printf("), rule %s, grid %dx%d, D=%d, %s, %d support vectors\n",
                model_.rule() == eskin::DecisionRule::kBinary ? "binary" : "one_vs_all",
                model_.rows(), model_.cols(), model_.D(), model_.is_float64() ? "float64" : "float32",
                model_.n_support());
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

template <typename T>
std::vector<T> decode(const std::uint8_t* p, std::size_t count) {
  std::vector<T> out(count);
  std::memcpy(out.data(), p, count * sizeof(T));  // little-endian host (x86, ARM)
  return out;
}

// ---- .npy
void classify_npy(const std::vector<std::uint8_t>& buf, const std::string& what, Printer& pr,
                  const eskin::Model& m) {
  if (buf.size() < 10) throw InputError(what + ": truncated .npy header");
  const int major = buf[6];
  std::size_t hlen, hstart;
  if (major == 1) {
    hlen = le16(&buf[8]);
    hstart = 10;
  } else if (major == 2 || major == 3) {
    if (buf.size() < 12) throw InputError(what + ": truncated .npy header");
    hlen = le32(&buf[8]);
    hstart = 12;
  } else {
    throw InputError(what + ": unsupported .npy version " + std::to_string(major));
  }
  if (hstart + hlen > buf.size()) throw InputError(what + ": truncated .npy header");
  const std::string h(reinterpret_cast<const char*>(&buf[hstart]), hlen);
  auto field = [&](const std::string& key) -> std::string {
    const std::size_t k = h.find("'" + key + "'");
    if (k == std::string::npos) throw InputError(what + ": .npy header has no '" + key + "'");
    std::size_t v = h.find(':', k);
    if (v == std::string::npos) throw InputError(what + ": malformed .npy header");
    ++v;
    while (v < h.size() && h[v] == ' ') ++v;
    std::size_t e = v;
    if (h[v] == '(') e = h.find(')', v) + 1;
    else if (h[v] == '\'') e = h.find('\'', v + 1) + 1;
    else e = h.find_first_of(",}", v);
    if (e == std::string::npos || e == 0 || e > h.size()) throw InputError(what + ": malformed .npy header");
    return h.substr(v, e - v);
  };
  const std::string descr = field("descr"), fortran = field("fortran_order"), shape_s = field("shape");
  if (fortran != "False") throw InputError(what + ": .npy array must be C order (fortran_order False)");
  std::vector<std::int64_t> shape;
  {
    std::size_t i = 1;
    while (i < shape_s.size()) {
      while (i < shape_s.size() && (shape_s[i] == ' ' || shape_s[i] == ',')) ++i;
      if (i >= shape_s.size() || shape_s[i] == ')') break;
      std::size_t used = 0;
      long long v = 0;
      try {
        v = std::stoll(shape_s.substr(i), &used);
      } catch (const std::exception&) {
        throw InputError(what + ": malformed .npy shape " + shape_s);
      }
      if (v < 0) throw InputError(what + ": negative .npy dimension");
      shape.push_back(v);
      i += used;
    }
  }
  std::int64_t n = 1, rows, cols, T;
  if (shape.size() == 3) {
    rows = shape[0];
    cols = shape[1];
    T = shape[2];
  } else if (shape.size() == 4) {
    n = shape[0];
    rows = shape[1];
    cols = shape[2];
    T = shape[3];
  } else {
    throw InputError(what + ": .npy shape " + shape_s + ", expected (rows, cols, T) or (n, rows, cols, T)");
  }
  if (rows != m.rows() || cols != m.cols())
    throw InputError(what + ": recordings are " + std::to_string(rows) + "x" + std::to_string(cols) +
                     " taxels, the model expects " + std::to_string(m.rows()) + "x" + std::to_string(m.cols()));
  if (T < 1) throw InputError(what + ": recordings have no samples (T = 0)");
  std::size_t item;
  if (descr == "'<i2'") item = 2;
  else if (descr == "'<f4'") item = 4;
  else if (descr == "'<f8'") item = 8;
  else throw InputError(what + ": .npy dtype " + descr + " not supported (int16, float32, float64 little-endian)");
  const std::size_t per = static_cast<std::size_t>(rows * cols * T);
  const std::size_t data_start = hstart + hlen;
  if (per > (buf.size() - data_start) / item || static_cast<std::size_t>(n) * per > (buf.size() - data_start) / item)
    throw InputError(what + ": .npy data truncated (" + std::to_string(buf.size() - data_start) +
                     " bytes for shape " + shape_s + ")");
  for (std::int64_t i = 0; i < n; ++i) {
    const std::uint8_t* p = &buf[data_start + static_cast<std::size_t>(i) * per * item];
    if (item == 2) pr.classify(decode<std::int16_t>(p, per).data(), static_cast<int>(rows), static_cast<int>(cols), T);
    else if (item == 4) pr.classify(decode<float>(p, per).data(), static_cast<int>(rows), static_cast<int>(cols), T);
    else pr.classify(decode<double>(p, per).data(), static_cast<int>(rows), static_cast<int>(cols), T);
  }
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
    data.resize(count);
    in.read(reinterpret_cast<char*>(data.data()), static_cast<std::streamsize>(count * 2));
    if (static_cast<std::size_t>(in.gcount()) != count * 2)
      throw InputError(rec + ": truncated samples (" + std::to_string(in.gcount()) + " of " +
                       std::to_string(count * 2) + " bytes)");
    pr.classify(data.data(), rows, cols, static_cast<std::int64_t>(T));
    std::fflush(stdout);
    hdr.clear();
    ++record;
  }
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
    const eskin::Model model = eskin::Model::load(model_path);
    Printer pr(model);
    std::ifstream file;
    std::istream* in = &std::cin;
    std::string what = "<stdin>";
    if (input != "-") {
      file.open(input, std::ios::binary);
      if (!file) throw InputError(input + ": cannot open");
      in = &file;
      what = input;
    }
    std::uint8_t magic[6];
    in->read(reinterpret_cast<char*>(magic), 6);
    const std::size_t got = static_cast<std::size_t>(in->gcount());
    pr.header(model_path);
    if (got == 6 && std::memcmp(magic, "\x93NUMPY", 6) == 0) {
      std::vector<std::uint8_t> buf(magic, magic + 6);
      const auto rest = read_all(*in);
      buf.insert(buf.end(), rest.begin(), rest.end());
      classify_npy(buf, what, pr, model);
    } else if (got == 0) {
      throw InputError(what + ": empty input");
    } else if (got >= 4 && std::memcmp(magic, "ESKR", 4) == 0) {
      classify_raw(*in, magic, got, what, pr, model);
    } else {
      throw InputError(what + ": neither a .npy file nor raw 'ESKR' records");
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
