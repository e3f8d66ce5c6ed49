// Interrupt-driven driver of the CMSDK APB UART (UART0 of QEMU's mps2-an386 at 0x40004000;
// one-byte buffers, no FIFO). Transmit: bytes are queued in a ring that the TX interrupt drains
// into the transmitter while it has room (one byte per interrupt on the hardware's one-byte
// buffer; a whole run of bytes per interrupt on QEMU, whose transmitter empties as each byte is
// written); the main loop starts an idle transmitter. Receive:
// the RX interrupt moves each byte into a small ring that the main loop reads. Heap-free.
#pragma once

#include <cstddef>
#include <cstdint>

namespace eskin::mcu {

/// Register offsets and bits (Arm CMSDK APB UART).
namespace uart_reg {
inline constexpr std::uintptr_t kUart0 = 0x40004000u;
inline constexpr std::uint32_t kData = 0x00, kState = 0x04, kCtrl = 0x08, kIntStatus = 0x0C,
                               kBaudDiv = 0x10;
inline constexpr std::uint32_t kCtrlTxEn = 1u << 0, kCtrlRxEn = 1u << 1, kCtrlTxInt = 1u << 2,
                               kCtrlRxInt = 1u << 3;
inline constexpr std::uint32_t kStateTxFull = 1u << 0, kStateRxFull = 1u << 1;
inline constexpr std::uint32_t kIntTx = 1u << 0, kIntRx = 1u << 1;
/// NVIC lines of UART0 on mps2-an386: RX 0, TX 1.
inline constexpr int kIrqRx = 0, kIrqTx = 1;
}  // namespace uart_reg

/// Transmit ring (bytes) and receive ring sizes; powers of two.
inline constexpr std::size_t kUartTxRing = 2048;
inline constexpr std::size_t kUartRxRing = 256;

class Uart {
 public:
  /// Enables TX and RX with their interrupts (baud divider 16: QEMU does not pace the line).
  void init();
  /// Bytes the transmit ring can take now.
  std::size_t tx_free() const;
  /// Queues n bytes if they all fit (never a partial write) and starts the line if idle.
  bool write(const std::uint8_t* p, std::size_t n);
  /// Moves up to cap received bytes out of the receive ring.
  std::size_t read(std::uint8_t* out, std::size_t cap);
  /// Receive bytes lost because the ring was full.
  std::uint32_t rx_overruns() const { return rx_overruns_; }
  std::uint64_t bytes_sent() const { return bytes_sent_; }
  /// TX interrupts handled (each sends a run of bytes the transmitter takes).
  std::uint32_t tx_interrupts() const { return tx_interrupts_; }

  /// Received bytes wait in the ring.
  bool rx_pending() const { return rx_head_ != rx_tail_; }
  /// Processor clock ticks spent in the UART's handlers (wraps at 2^32: take differences).
  std::uint32_t isr_ticks() const { return isr_ticks_; }

  // interrupt handlers' work
  void on_tx_interrupt();
  void on_rx_interrupt();

 private:
  void kick();
  bool fill_transmitter();
  std::uint8_t tx_[kUartTxRing];
  volatile std::uint32_t tx_head_ = 0;  // written by the main loop
  volatile std::uint32_t tx_tail_ = 0;  // written by the TX interrupt
  volatile bool tx_busy_ = false;       // a TX interrupt will follow (bytes are in flight)
  std::uint8_t rx_[kUartRxRing];
  volatile std::uint32_t rx_head_ = 0;  // written by the RX interrupt
  volatile std::uint32_t rx_tail_ = 0;  // written by the main loop
  volatile std::uint32_t rx_overruns_ = 0;
  volatile std::uint64_t bytes_sent_ = 0;
  volatile std::uint32_t tx_interrupts_ = 0;
  volatile std::uint32_t isr_ticks_ = 0;
};

/// The board's UART0 (its interrupt handlers call into it).
Uart& uart0();

}  // namespace eskin::mcu
