// Bindings for the wire protocol (eskin/protocol.hpp): frames cross as dicts whose keys are the
// field names of the Python dataclasses in eskin.protocol; DATA samples as int16 arrays
// shaped (n_samples, rows, cols).
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "eskin/protocol.hpp"

namespace py = pybind11;

namespace eskin::bindings {
namespace {

using protocol::Frame;
using protocol::FrameType;

std::string_view as_view(const py::bytes& b) {
  char* data = nullptr;
  Py_ssize_t len = 0;
  PyBytes_AsStringAndSize(b.ptr(), &data, &len);
  return {data, static_cast<std::size_t>(len)};
}

py::bytes to_bytes(const std::uint8_t* p, std::size_t n) {
  return py::bytes(reinterpret_cast<const char*>(p), n);
}

template <class T>
T get(const py::dict& d, const char* key, T fallback) {
  if (!d.contains(key)) return fallback;
  return d[key].cast<T>();
}

template <class T>
T get_checked(const py::dict& d, const char* key, T fallback, long long lo, long long hi) {
  if (!d.contains(key)) return fallback;
  const auto v = d[key].cast<long long>();
  if (v < lo || v > hi)
    throw std::invalid_argument(std::string("frame field ") + key + " = " + std::to_string(v) +
                                " is out of range [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "]");
  return static_cast<T>(v);
}

std::uint64_t get_u64(const py::dict& d, const char* key) {
  if (!d.contains(key)) return 0;
  const py::int_ v = d[key].cast<py::int_>();
  if (v < py::int_(0))
    throw std::invalid_argument(std::string("frame field ") + key + " must be >= 0, got " +
                                std::string(py::str(v)));
  return v.cast<std::uint64_t>();
}

py::dict frame_to_dict(const Frame& f) {
  py::dict d;
  d["type"] = static_cast<int>(f.type);
  d["flags"] = f.flags;
  d["seq"] = f.seq;
  switch (f.type) {
    case FrameType::data: {
      const auto& p = f.data;
      d["first_sample"] = p.first_sample;
      d["timestamp_us"] = p.timestamp_us;
      py::array_t<std::int16_t> a({static_cast<py::ssize_t>(p.n_samples),
                                   static_cast<py::ssize_t>(p.rows),
                                   static_cast<py::ssize_t>(p.cols)});
      std::memcpy(a.mutable_data(), p.samples,
                  sizeof(std::int16_t) * p.n_samples * p.rows * p.cols);
      d["samples"] = std::move(a);
      break;
    }
    case FrameType::decision: {
      const auto& p = f.decision;
      d["onset_sample"] = p.onset_sample;
      d["offset_sample"] = p.offset_sample;
      d["decided_sample"] = p.decided_sample;
      d["timestamp_us"] = p.timestamp_us;
      d["latency_us"] = p.latency_us;
      d["label"] = p.label;
      d["dont_know"] = p.dont_know != 0;
      py::tuple values(p.n_values);
      for (std::size_t i = 0; i < p.n_values; ++i) values[i] = p.values[i];
      d["values"] = values;
      break;
    }
    case FrameType::status: {
      const auto& p = f.status;
      d["uptime_us"] = p.uptime_us;
      d["next_sample"] = p.next_sample;
      d["samples_sent"] = p.samples_sent;
      d["dropped_samples"] = p.dropped_samples;
      d["overrun_events"] = p.overrun_events;
      d["rx_errors"] = p.rx_errors;
      d["faults_injected"] = p.faults_injected;
      d["decisions_sent"] = p.decisions_sent;
      d["pacing_p50_ns"] = p.pacing_p50_ns;
      d["pacing_p99_ns"] = p.pacing_p99_ns;
      d["pacing_max_ns"] = p.pacing_max_ns;
      d["state"] = static_cast<int>(p.state);
      d["host_connected"] = p.host_connected != 0;
      d["connections"] = p.connections;
      d["decisions_dropped"] = p.decisions_dropped;
      d["frames_dropped"] = p.frames_dropped;
      break;
    }
    case FrameType::info: {
      const auto& p = f.info;
      d["rows"] = p.rows;
      d["cols"] = p.cols;
      d["samples_per_frame"] = p.samples_per_frame;
      d["protocol_version"] = p.protocol_version;
      d["has_model"] = p.has_model != 0;
      d["sample_rate_hz"] = p.sample_rate_hz;
      d["volts_per_count"] = p.volts_per_count;
      d["speed"] = p.speed;
      // Names are UTF-8 separated by '\n'; invalid bytes are replaced, never raised.
      py::object text = py::reinterpret_steal<py::object>(
          PyUnicode_DecodeUTF8(p.class_names, p.names_len, "replace"));
      py::list names;
      if (p.names_len > 0) names = text.attr("split")("\n");
      if (names.size() != p.n_classes) {
        // keep the declared count authoritative: pad or cut
        py::list fixed;
        for (std::size_t i = 0; i < p.n_classes; ++i)
          fixed.append(i < names.size() ? names[i] : py::str(""));
        names = fixed;
      }
      d["class_names"] = py::tuple(names);
      break;
    }
    case FrameType::ping:
    case FrameType::pong:
      d["token"] = f.ping.token;
      d["timestamp_us"] = f.ping.timestamp_us;
      break;
    case FrameType::start:
    case FrameType::stop:
    case FrameType::info_request:
      break;
  }
  return d;
}

py::bytes encode_dict(const py::dict& d) {
  if (!d.contains("type")) throw std::invalid_argument("frame dict needs a 'type'");
  const int type = d["type"].cast<int>();
  if (type < 0 || type > 255 || !protocol::is_known_type(static_cast<std::uint8_t>(type)))
    throw std::invalid_argument("unknown frame type " + std::to_string(type));
  Frame f;
  f.type = static_cast<FrameType>(type);
  f.flags = get_checked<std::uint8_t>(d, "flags", 0, 0, 255);
  f.seq = get_checked<std::uint16_t>(d, "seq", 0, 0, 65535);
  py::array_t<std::int16_t, py::array::c_style> samples;
  std::string names;
  switch (f.type) {
    case FrameType::data: {
      auto& p = f.data;
      p.first_sample = get_u64(d, "first_sample");
      p.timestamp_us = get_u64(d, "timestamp_us");
      if (!d.contains("samples")) throw std::invalid_argument("DATA frame needs 'samples'");
      py::array raw = py::array::ensure(d["samples"]);
      if (!raw || raw.ndim() != 3)
        throw std::invalid_argument("DATA samples must be a 3-d array (n_samples, rows, cols)");
      if (raw.dtype().kind() != 'i' && raw.dtype().kind() != 'u')
        throw std::invalid_argument("DATA samples must be integer ADC codes, got dtype " +
                                    std::string(py::str(raw.dtype())));
      samples = py::array_t<std::int16_t, py::array::c_style | py::array::forcecast>(raw);
      if (samples.shape(0) < 1 || samples.shape(0) > 65535 || samples.shape(1) < 1 ||
          samples.shape(1) > 255 || samples.shape(2) < 1 || samples.shape(2) > 255)
        throw std::invalid_argument(
            "DATA samples shape (" + std::to_string(samples.shape(0)) + ", " +
            std::to_string(samples.shape(1)) + ", " + std::to_string(samples.shape(2)) +
            ") is not (1..65535, 1..255, 1..255)");
      p.n_samples = static_cast<std::uint16_t>(samples.shape(0));
      p.rows = static_cast<std::uint8_t>(samples.shape(1));
      p.cols = static_cast<std::uint8_t>(samples.shape(2));
      p.samples = samples.data();
      break;
    }
    case FrameType::decision: {
      auto& p = f.decision;
      p.onset_sample = get_u64(d, "onset_sample");
      p.offset_sample = get_u64(d, "offset_sample");
      p.decided_sample = get_u64(d, "decided_sample");
      p.timestamp_us = get_u64(d, "timestamp_us");
      p.latency_us = get_checked<std::uint32_t>(d, "latency_us", 0, 0, 0xFFFFFFFFLL);
      p.label = get_checked<std::int16_t>(d, "label", -1, -32768, 32767);
      p.dont_know = get(d, "dont_know", false) ? 1 : 0;
      const auto values = get(d, "values", std::vector<double>{});
      if (values.size() > protocol::kMaxDecisionValues)
        throw std::invalid_argument("DECISION carries at most " +
                                    std::to_string(protocol::kMaxDecisionValues) +
                                    " values, got " + std::to_string(values.size()));
      p.n_values = static_cast<std::uint8_t>(values.size());
      for (std::size_t i = 0; i < values.size(); ++i) p.values[i] = values[i];
      break;
    }
    case FrameType::status: {
      auto& p = f.status;
      p.uptime_us = get_u64(d, "uptime_us");
      p.next_sample = get_u64(d, "next_sample");
      p.samples_sent = get_u64(d, "samples_sent");
      p.dropped_samples = get_u64(d, "dropped_samples");
      constexpr long long kU32 = 0xFFFFFFFFLL;
      p.overrun_events = get_checked<std::uint32_t>(d, "overrun_events", 0, 0, kU32);
      p.rx_errors = get_checked<std::uint32_t>(d, "rx_errors", 0, 0, kU32);
      p.faults_injected = get_checked<std::uint32_t>(d, "faults_injected", 0, 0, kU32);
      p.decisions_sent = get_checked<std::uint32_t>(d, "decisions_sent", 0, 0, kU32);
      p.pacing_p50_ns = get_checked<std::uint32_t>(d, "pacing_p50_ns", 0, 0, kU32);
      p.pacing_p99_ns = get_checked<std::uint32_t>(d, "pacing_p99_ns", 0, 0, kU32);
      p.pacing_max_ns = get_checked<std::uint32_t>(d, "pacing_max_ns", 0, 0, kU32);
      p.state = static_cast<protocol::StreamState>(get_checked<std::uint8_t>(d, "state", 0, 0, 2));
      p.host_connected = get(d, "host_connected", false) ? 1 : 0;
      p.connections = get_checked<std::uint16_t>(d, "connections", 0, 0, 65535);
      p.decisions_dropped = get_checked<std::uint32_t>(d, "decisions_dropped", 0, 0, kU32);
      p.frames_dropped = get_checked<std::uint32_t>(d, "frames_dropped", 0, 0, kU32);
      break;
    }
    case FrameType::info: {
      auto& p = f.info;
      p.rows = get_checked<std::uint8_t>(d, "rows", 0, 0, 255);
      p.cols = get_checked<std::uint8_t>(d, "cols", 0, 0, 255);
      p.samples_per_frame = get_checked<std::uint16_t>(d, "samples_per_frame", 0, 0, 65535);
      p.protocol_version = get_checked<std::uint16_t>(d, "protocol_version",
                                                      protocol::kProtocolVersion, 0, 65535);
      p.has_model = get(d, "has_model", false) ? 1 : 0;
      p.sample_rate_hz = get(d, "sample_rate_hz", 0.0);
      p.volts_per_count = get(d, "volts_per_count", 0.0);
      p.speed = get(d, "speed", 1.0);
      const auto list = get(d, "class_names", std::vector<std::string>{});
      if (list.size() > 255)
        throw std::invalid_argument("INFO carries at most 255 class names, got " +
                                    std::to_string(list.size()));
      for (std::size_t i = 0; i < list.size(); ++i) {
        if (list[i].find('\n') != std::string::npos)
          throw std::invalid_argument("class name " + std::to_string(i) +
                                      " contains a newline");
        if (i) names += '\n';
        names += list[i];
      }
      if (names.size() > 65535) throw std::invalid_argument("INFO class names too long");
      p.n_classes = static_cast<std::uint8_t>(list.size());
      p.names_len = static_cast<std::uint16_t>(names.size());
      p.class_names = names.data();
      break;
    }
    case FrameType::ping:
    case FrameType::pong:
      f.ping.token = get_checked<std::uint32_t>(d, "token", 0, 0, 0xFFFFFFFFLL);
      f.ping.timestamp_us = get_u64(d, "timestamp_us");
      break;
    case FrameType::start:
    case FrameType::stop:
    case FrameType::info_request:
      break;
  }
  std::vector<std::uint8_t> out(protocol::kMaxEncodedFrameSize);
  protocol::FrameEncoder enc;
  const std::size_t n = enc.encode(f, out.data(), out.size());
  if (n == 0)
    throw std::invalid_argument(std::string("cannot encode ") + protocol::frame_type_name(f.type) +
                                " frame: " + protocol::encode_status_message(enc.status()) +
                                " (a frame holds at most " +
                                std::to_string(protocol::kMaxFrameSize) + " bytes)");
  return to_bytes(out.data(), n);
}

py::dict stats_to_dict(const protocol::DecoderStats& s) {
  py::dict d;
  d["bytes"] = s.bytes;
  d["skipped_bytes"] = s.skipped_bytes;
  d["frames"] = s.frames;
  d["data_frames"] = s.data_frames;
  d["samples"] = s.samples;
  d["crc_errors"] = s.crc_errors;
  d["malformed"] = s.malformed;
  d["oversize"] = s.oversize;
  d["sequence_gaps"] = s.sequence_gaps;
  d["lost_frames"] = s.lost_frames;
  d["lost_samples"] = s.lost_samples;
  d["sample_index_resets"] = s.sample_index_resets;
  return d;
}

}  // namespace

void bind_protocol(py::module_& m) {
  auto p = m.def_submodule("protocol", "eskin wire protocol (COBS + CRC-32 frames)");
  p.attr("PROTOCOL_VERSION") = protocol::kProtocolVersion;
  p.attr("MAX_FRAME_SIZE") = protocol::kMaxFrameSize;
  p.attr("MAX_DECISION_VALUES") = protocol::kMaxDecisionValues;
  // The protocol's numbering as the C++ core has it (eskin.link.protocol's enums are checked
  // against these by tests/python/link/test_protocol.py).
  py::dict types;
  for (int t = 0; t < 256; ++t)
    if (protocol::is_known_type(static_cast<std::uint8_t>(t)))
      types[protocol::frame_type_name(static_cast<protocol::FrameType>(t))] = t;
  p.attr("FRAME_TYPES") = types;
  py::dict flag_bits;
  flag_bits["OVERRUN"] = protocol::flags::kOverrun;
  flag_bits["SYNC"] = protocol::flags::kSync;
  flag_bits["LOOP"] = protocol::flags::kLoop;
  p.attr("FLAGS") = flag_bits;
  py::dict states;
  states["STOPPED"] = static_cast<int>(protocol::StreamState::stopped);
  states["STREAMING"] = static_cast<int>(protocol::StreamState::streaming);
  states["FINISHED"] = static_cast<int>(protocol::StreamState::finished);
  p.attr("STREAM_STATES") = states;
  p.attr("DELIMITER") = py::bytes(reinterpret_cast<const char*>(&protocol::kDelimiter), 1);

  p.def(
      "crc32",
      [](const py::bytes& data, std::uint32_t crc) {
        const auto v = as_view(data);
        return protocol::crc32(reinterpret_cast<const std::uint8_t*>(v.data()), v.size(), crc);
      },
      py::arg("data"), py::arg("crc") = 0, "CRC-32 (zlib / ISO-HDLC), same as zlib.crc32");
  p.def(
      "cobs_encode",
      [](const py::bytes& data) {
        const auto v = as_view(data);
        std::vector<std::uint8_t> out(protocol::max_encoded_size(v.size()));
        const std::size_t n = protocol::cobs_encode(
            reinterpret_cast<const std::uint8_t*>(v.data()), v.size(), out.data(), out.size());
        return to_bytes(out.data(), n);
      },
      py::arg("data"), "COBS-encode bytes (no delimiter appended)");
  p.def(
      "cobs_decode",
      [](const py::bytes& data) {
        const auto v = as_view(data);
        std::vector<std::uint8_t> out(v.size() + 1);
        const auto n = protocol::cobs_decode(reinterpret_cast<const std::uint8_t*>(v.data()),
                                             v.size(), out.data(), out.size());
        if (n < 0) throw std::invalid_argument("not a valid COBS block");
        return to_bytes(out.data(), static_cast<std::size_t>(n));
      },
      py::arg("data"), "Decode one COBS block (no delimiter inside); ValueError if invalid");
  p.def("encode", &encode_dict, py::arg("frame"),
        "Encode a frame given as a dict (keys: type, flags, seq and the payload fields) into "
        "its COBS bytes and trailing 0x00 delimiter");

  py::class_<protocol::FrameDecoder>(p, "FrameDecoder")
      .def(py::init<std::size_t, bool>(), py::arg("max_frame_size") = protocol::kMaxFrameSize,
           py::arg("wait_for_delimiter") = true)
      .def(
          "feed",
          [](protocol::FrameDecoder& dec, const py::buffer& data) {
            const py::buffer_info info = data.request();
            if (info.itemsize != 1 || info.ndim > 1 || (info.ndim == 1 && info.strides[0] != 1))
              throw std::invalid_argument("feed() takes bytes (a contiguous byte buffer)");
            const auto* ptr = static_cast<const std::uint8_t*>(info.ptr);
            const std::size_t n = static_cast<std::size_t>(info.size * info.itemsize);
            py::list frames;
            dec.feed_all(ptr, n, [&](const Frame& f) { frames.append(frame_to_dict(f)); });
            return frames;
          },
          py::arg("data"), "Feed bytes; returns the accepted frames as dicts")
      .def("stats", [](const protocol::FrameDecoder& dec) { return stats_to_dict(dec.stats()); })
      .def("reset", &protocol::FrameDecoder::reset, py::arg("reset_stats") = false)
      .def_property_readonly("max_frame_size", &protocol::FrameDecoder::max_frame_size);
}

}  // namespace eskin::bindings
