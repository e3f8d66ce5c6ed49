// Bindings for the serial port (eskin/serial_port.hpp). Transfers return (bytes, status) pairs;
// eskin.serial_port turns failing statuses into exceptions. Blocking calls release the GIL.
#include <pybind11/stl.h>

#include <string>
#include <vector>

#include "bindings.hpp"
#include "eskin/serial_port.hpp"

namespace py = pybind11;

namespace eskin::bindings {
namespace {

using serial::IoResult;
using serial::PortReader;
using serial::PortStatus;
using serial::SerialPort;

int timeout_ms(double timeout_s) {
  if (timeout_s < 0) return -1;
  const double ms = timeout_s * 1000.0;
  return ms > 2.0e9 ? 2000000000 : static_cast<int>(ms + 0.5);
}

py::tuple read_result(std::vector<std::uint8_t>& buf, const IoResult& r) {
  return py::make_tuple(py::bytes(reinterpret_cast<const char*>(buf.data()), r.bytes),
                        py::str(serial::port_status_name(r.status)));
}

std::string_view view(const py::bytes& b) {
  char* data = nullptr;
  Py_ssize_t len = 0;
  PyBytes_AsStringAndSize(b.ptr(), &data, &len);
  return {data, static_cast<std::size_t>(len)};
}

void bind_port_reader(py::module_& s) {
  py::class_<PortReader>(s, "PortReader")
      .def(py::init<const SerialPort&, std::size_t, std::size_t, int, int>(), py::arg("port"),
           py::arg("capacity"), py::arg("trickle_bytes") = 0, py::arg("trickle_wait_ms") = 0,
           py::arg("realtime_priority") = 0, py::keep_alive<1, 2>())
      .def("start", [](PortReader& r) { return serial::port_status_name(r.start()); })
      .def("stop", &PortReader::stop, py::call_guard<py::gil_scoped_release>())
      .def(
          "take",
          [](PortReader& r, std::size_t size, double timeout_s) {
            std::vector<std::uint8_t> buf(size);
            IoResult res;
            {
              py::gil_scoped_release nogil;
              res = r.take(buf.data(), size, timeout_ms(timeout_s));
            }
            return read_result(buf, res);
          },
          py::arg("size"), py::arg("timeout_s"))
      .def_property_readonly("realtime", &PortReader::realtime)
      .def_property_readonly("queued", &PortReader::queued)
      .def_property_readonly("peak", &PortReader::peak)
      .def_property_readonly("overflow", &PortReader::overflow)
      .def_property_readonly("bytes_read", &PortReader::bytes_read)
      .def_property_readonly("last_error", &PortReader::last_error);
}

}  // namespace

void bind_serial(py::module_& m) {
  auto s = m.def_submodule("serial", "termios serial port (also opens pseudo-terminals)");
  py::class_<SerialPort>(s, "SerialPort")
      .def(py::init<>())
      .def(
          "open",
          [](SerialPort& p, const std::string& path, std::uint32_t baud) {
            return serial::port_status_name(p.open(path, baud));
          },
          py::arg("path"), py::arg("baud") = 115200)
      .def("close", [](SerialPort& p) { return serial::port_status_name(p.close()); })
      .def("set_baud",
           [](SerialPort& p, std::uint32_t baud) { return serial::port_status_name(p.set_baud(baud)); })
      .def_property_readonly("is_open", &SerialPort::is_open)
      .def_property_readonly("fd", &SerialPort::fd)
      .def_property_readonly("path", &SerialPort::path)
      .def_property_readonly("baud", &SerialPort::baud)
      .def_property_readonly("last_error", &SerialPort::last_error)
      .def_property_readonly("last_errno", &SerialPort::last_errno)
      .def(
          "blocking_read",
          [](SerialPort& p, std::size_t size, double timeout_s) {
            std::vector<std::uint8_t> buf(size);
            IoResult r;
            {
              py::gil_scoped_release nogil;
              r = p.blocking_read(buf.data(), size, timeout_ms(timeout_s));
            }
            return read_result(buf, r);
          },
          py::arg("size"), py::arg("timeout_s"))
      .def(
          "blocking_read_next",
          [](SerialPort& p, std::size_t size, double timeout_s) {
            std::vector<std::uint8_t> buf(size);
            IoResult r;
            {
              py::gil_scoped_release nogil;
              r = p.blocking_read_next(buf.data(), size, timeout_ms(timeout_s));
            }
            return read_result(buf, r);
          },
          py::arg("size"), py::arg("timeout_s"))
      .def(
          "nonblocking_read",
          [](SerialPort& p, std::size_t size) {
            std::vector<std::uint8_t> buf(size);
            const IoResult r = p.nonblocking_read(buf.data(), size);
            return read_result(buf, r);
          },
          py::arg("size"))
      .def(
          "blocking_write",
          [](SerialPort& p, const py::bytes& data, double timeout_s) {
            const std::string_view v = view(data);
            IoResult r;
            {
              py::gil_scoped_release nogil;
              r = p.blocking_write(reinterpret_cast<const std::uint8_t*>(v.data()), v.size(),
                                   timeout_ms(timeout_s));
            }
            return py::make_tuple(r.bytes, serial::port_status_name(r.status));
          },
          py::arg("data"), py::arg("timeout_s"))
      .def(
          "nonblocking_write",
          [](SerialPort& p, const py::bytes& data) {
            const std::string_view v = view(data);
            const IoResult r =
                p.nonblocking_write(reinterpret_cast<const std::uint8_t*>(v.data()), v.size());
            return py::make_tuple(r.bytes, serial::port_status_name(r.status));
          },
          py::arg("data"))
      .def("input_waiting",
           [](SerialPort& p) {
             const IoResult r = p.input_waiting();
             return py::make_tuple(r.bytes, serial::port_status_name(r.status));
           })
      .def("output_waiting",
           [](SerialPort& p) {
             const IoResult r = p.output_waiting();
             return py::make_tuple(r.bytes, serial::port_status_name(r.status));
           })
      .def(
          "flush",
          [](SerialPort& p, bool input, bool output) {
            if (!input && !output) return serial::port_status_name(PortStatus::ok);
            const auto which = input && output ? serial::Buffers::both
                               : input         ? serial::Buffers::input
                                               : serial::Buffers::output;
            return serial::port_status_name(p.flush(which));
          },
          py::arg("input") = true, py::arg("output") = true)
      .def(
          "drain",
          [](SerialPort& p, double timeout_s) {
            PortStatus st;
            {
              py::gil_scoped_release nogil;
              st = p.drain(timeout_ms(timeout_s));
            }
            return serial::port_status_name(st);
          },
          py::arg("timeout_s"));
  bind_port_reader(s);
}

}  // namespace eskin::bindings
