// CRC-32 of the core: one table, one function, used by the wire protocol (frames, replay files)
// and the model format (.eskin trailer).
#pragma once

#include <cstddef>
#include <cstdint>

namespace eskin {

/// CRC-32 with the zlib polynomial (ISO-HDLC: reflected 0xEDB88320, init and final xor
/// 0xFFFFFFFF), equal to Python's zlib.crc32. Pass a previous result as `crc` to continue a
/// running checksum (start with 0). Heap-free; `data` may be null when `size` is 0.
std::uint32_t crc32(const std::uint8_t* data, std::size_t size, std::uint32_t crc = 0) noexcept;

}  // namespace eskin
