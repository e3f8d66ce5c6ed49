// libFuzzer harness of the wire protocol's streaming frame decoder (cpp/src/protocol.cpp): any
// byte stream, fed in pieces whose sizes the input chooses, with the full and a small frame
// limit, or frames built by the harness (below). The decoder must never crash, never read out of bounds and keep its counters
// consistent; every accepted frame is read in full (so ASan sees any bad pointer in it).
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "eskin/protocol.hpp"

namespace proto = eskin::protocol;

namespace {

std::uint64_t touch(const proto::Frame& f) {
  std::uint64_t h = f.seq + f.flags + static_cast<std::uint64_t>(f.type);
  switch (f.type) {
    case proto::FrameType::data:
      for (std::size_t i = 0; i < std::size_t{f.data.n_samples} * f.data.rows * f.data.cols; ++i)
        h += static_cast<std::uint16_t>(f.data.samples[i]);
      break;
    case proto::FrameType::decision:
      for (std::size_t i = 0; i < f.decision.n_values; ++i) h += static_cast<std::uint64_t>(f.decision.values[i] != 0);
      break;
    case proto::FrameType::info:
      for (std::size_t i = 0; i < f.info.names_len; ++i) h += static_cast<unsigned char>(f.info.class_names[i]);
      break;
    default:
      break;
  }
  return h;
}

void run(const std::uint8_t* data, std::size_t size, std::size_t max_frame, std::size_t step) {
  proto::FrameDecoder dec(max_frame, step % 2 == 0);
  std::uint64_t h = 0;
  std::size_t frames = 0;
  while (size > 0) {
    const std::size_t n = step < size ? step : size;
    const std::size_t used = dec.feed(data, n);
    if (used == 0 || used > n) std::abort();  // the decoder must make progress within its input
    data += used;
    size -= used;
    if (dec.has_frame()) {
      h += touch(dec.frame());
      ++frames;
    }
  }
  const auto& s = dec.stats();
  if (s.frames != frames || s.data_frames > s.frames) std::abort();
  if (h == 0x9E3779B97F4A7C15ull) std::abort();  // keeps the reads
}

// Frames mode: the input is a list of raw frames (u16 length, then header and payload); each
// gets its CRC-32 and COBS encoding here, so that mutations of the payloads reach the layout
// checks of every frame type instead of stopping at the checksum.
std::vector<std::uint8_t> encode_raw_frames(const std::uint8_t* data, std::size_t size) {
  std::vector<std::uint8_t> stream(1, 0), raw, block;
  while (size >= 2) {
    std::size_t n = std::size_t{data[0]} | (std::size_t{data[1]} << 8);
    data += 2;
    size -= 2;
    if (n > size) n = size;
    raw.assign(data, data + n);
    data += n;
    size -= n;
    const std::uint32_t crc = proto::crc32(raw.data(), raw.size());
    for (int i = 0; i < 4; ++i) raw.push_back(static_cast<std::uint8_t>(crc >> (8 * i)));
    block.resize(proto::max_encoded_size(raw.size()));
    const std::size_t m = proto::cobs_encode(raw.data(), raw.size(), block.data(), block.size());
    stream.insert(stream.end(), block.begin(), block.begin() + static_cast<std::ptrdiff_t>(m));
    stream.push_back(0);
  }
  return stream;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const std::size_t step = 1 + data[0] % 97;  // feed in pieces of 1..97 bytes
  if (data[0] & 0x80) {
    const std::vector<std::uint8_t> stream = encode_raw_frames(data + 1, size - 1);
    run(stream.data(), stream.size(), proto::kMaxFrameSize, step);
    return 0;
  }
  run(data + 1, size - 1, proto::kMaxFrameSize, step);
  run(data + 1, size - 1, 64, size);  // a small limit: long blocks are oversize
  return 0;
}
