// The .npy reader of the core (NumPy format versions 1.0, 2.0 and 3.0), shared by the tools
// that take raw recordings as .npy files (eskin-classify, eskin-fw-sim).
//
// It parses and validates the header only; the caller maps or reads the data, whose size the
// header declares. Every declared size is checked against a documented limit and against the
// bytes the file really holds before the caller allocates anything (docs/model-format.md, "Raw
// recordings"). Errors are NpyError (a std::runtime_error) whose message names the file, the
// field and the value.
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace eskin {

class NpyError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The element types eskin reads: little-endian int16 (ADC codes), float32, float64.
enum class NpyDtype : int { kInt16 = 0, kFloat32 = 1, kFloat64 = 2 };
std::size_t npy_item_bytes(NpyDtype dtype) noexcept;
const char* npy_descr(NpyDtype dtype) noexcept;  ///< "<i2", "<f4", "<f8"

/// Limits (NumPy itself refuses headers over 10000 bytes unless told otherwise).
inline constexpr std::size_t kNpyMaxHeaderBytes = 65536;           ///< the header dictionary
inline constexpr std::size_t kNpyMaxDims = 8;                       ///< entries of 'shape'
inline constexpr std::uint64_t kNpyMaxDataBytes = std::uint64_t{1} << 40;  ///< 1 TiB of data
/// Bytes of the fixed preamble (magic, version, header length) in every version.
inline constexpr std::size_t kNpyPreambleBytes = 12;

struct NpyHeader {
  int major_version = 1;
  NpyDtype dtype = NpyDtype::kInt16;
  std::vector<std::uint64_t> shape;
  std::uint64_t count = 1;        ///< elements: the product of shape
  std::uint64_t data_bytes = 0;   ///< count * item size, at most kNpyMaxDataBytes
  std::size_t data_offset = 0;    ///< where the data starts (magic + preamble + header)
  std::size_t item_bytes() const noexcept { return npy_item_bytes(dtype); }
};

/// True when the bytes start with the .npy magic ("\x93NUMPY").
bool is_npy(const std::uint8_t* p, std::size_t size) noexcept;

/// Where the data starts, read from the preamble: `size` must be at least kNpyPreambleBytes
/// (or the whole file when shorter). Throws NpyError for a bad magic, an unknown version, a
/// header length over kNpyMaxHeaderBytes, or a truncated preamble. `what` names the input.
std::size_t npy_data_offset(const std::uint8_t* p, std::size_t size, const std::string& what);

/// Parses the header of a .npy image: p[0, size) must hold at least npy_data_offset() bytes
/// (the data may follow). Checks the dictionary (exactly 'descr', 'fortran_order' = False and
/// 'shape', as NumPy writes them), the dtype, and the declared data size against
/// kNpyMaxDataBytes. It does not look at the data.
NpyHeader parse_npy_header(const std::uint8_t* p, std::size_t size, const std::string& what);

/// Throws NpyError unless a file of `file_bytes` bytes holds exactly the header and its data
/// (truncated data, or bytes after it).
void check_npy_file_size(const NpyHeader& h, std::uint64_t file_bytes, const std::string& what);

/// The shape as NumPy prints it, e.g. "(3, 4, 4, 900)".
std::string npy_shape_string(const std::vector<std::uint64_t>& shape);

}  // namespace eskin
