#include "cmsdk_uart.hpp"

#include "board_irq.hpp"
#include "mcu_board.h"

namespace eskin::mcu {

namespace {

/// Clock ticks since `entry`; 0 for a reading that went backwards (a SysTick wrap-around not
/// yet counted: the handler's own time is then not accounted).
inline std::uint32_t clock_delta(std::uint64_t entry) {
  const std::uint64_t d = mcu_ticks() - entry;
  return d < (1u << 24) ? static_cast<std::uint32_t>(d) : 0u;
}

inline volatile std::uint32_t& reg(std::uint32_t off) {
  return *reinterpret_cast<volatile std::uint32_t*>(uart_reg::kUart0 + off);
}

Uart g_uart0;

}  // namespace

Uart& uart0() { return g_uart0; }

void Uart::init() {
  using namespace uart_reg;
  reg(kCtrl) = 0;
  reg(kBaudDiv) = 16;
  reg(kIntStatus) = kIntTx | kIntRx;  // INTCLEAR
  reg(kCtrl) = kCtrlTxEn | kCtrlRxEn | kCtrlTxInt | kCtrlRxInt;
  irq_set_priority(kIrqRx, 0x40);
  irq_set_priority(kIrqTx, 0x40);
  irq_enable(kIrqRx);
  irq_enable(kIrqTx);
}

std::size_t Uart::tx_free() const {
  return kUartTxRing - static_cast<std::size_t>(tx_head_ - tx_tail_);
}

bool Uart::write(const std::uint8_t* p, std::size_t n) {
  if (n > tx_free()) return false;
  std::uint32_t h = tx_head_;
  for (std::size_t i = 0; i < n; ++i, ++h) tx_[h & (kUartTxRing - 1)] = p[i];
  compiler_barrier();
  tx_head_ = h;
  kick();
  return true;
}

/// Moves bytes from the ring into the transmitter while it has room (TXFULL clear): one byte on
/// the CMSDK UART's one-byte buffer, as many as the port takes at once where the transmitter
/// empties at once (QEMU's model hands each byte to its character device as it is written).
/// Returns whether a TX interrupt will follow: a byte was written, or one is still in flight.
bool Uart::fill_transmitter() {
  using namespace uart_reg;
  std::uint32_t t = tx_tail_;
  const std::uint32_t h = tx_head_;
  bool wrote = false;
  while (t != h && !(reg(kState) & kStateTxFull)) {
    reg(kData) = tx_[t & (kUartTxRing - 1)];
    ++t;
    wrote = true;
  }
  bytes_sent_ = bytes_sent_ + (t - tx_tail_);
  tx_tail_ = t;
  return wrote || (reg(kState) & kStateTxFull) != 0;
}

/// Starts an idle transmitter with one byte; the TX interrupt sends the rest (there, at the
/// UART's priority, the sampling timer can interrupt a long run of bytes; here interrupts are
/// masked).
void Uart::kick() {
  const std::uint32_t primask = irq_save();
  const std::uint32_t t = tx_tail_;
  if (!tx_busy_ && t != tx_head_ && !(reg(uart_reg::kState) & uart_reg::kStateTxFull)) {
    reg(uart_reg::kData) = tx_[t & (kUartTxRing - 1)];
    tx_tail_ = t + 1;
    bytes_sent_ = bytes_sent_ + 1;
    tx_busy_ = true;
  }
  irq_restore(primask);
}

void Uart::on_tx_interrupt() {
  const std::uint64_t entry = g_profile ? mcu_ticks() : 0;
  reg(uart_reg::kIntStatus) = uart_reg::kIntTx;  // INTCLEAR
  tx_interrupts_ = tx_interrupts_ + 1;
  tx_busy_ = fill_transmitter();
  if (g_profile) isr_ticks_ = isr_ticks_ + clock_delta(entry);
}

void Uart::on_rx_interrupt() {
  const std::uint64_t entry = g_profile ? mcu_ticks() : 0;
  reg(uart_reg::kIntStatus) = uart_reg::kIntRx;  // INTCLEAR
  while (reg(uart_reg::kState) & uart_reg::kStateRxFull) {
    const std::uint8_t b = static_cast<std::uint8_t>(reg(uart_reg::kData));
    const std::uint32_t h = rx_head_;
    if (h - rx_tail_ < kUartRxRing) {
      rx_[h & (kUartRxRing - 1)] = b;
      rx_head_ = h + 1;
    } else {
      rx_overruns_ = rx_overruns_ + 1;
    }
  }
  if (g_profile) isr_ticks_ = isr_ticks_ + clock_delta(entry);
}

std::size_t Uart::read(std::uint8_t* out, std::size_t cap) {
  std::size_t n = 0;
  std::uint32_t t = rx_tail_;
  const std::uint32_t h = rx_head_;
  while (t != h && n < cap) out[n++] = rx_[t++ & (kUartRxRing - 1)];
  compiler_barrier();
  rx_tail_ = t;
  return n;
}

}  // namespace eskin::mcu

extern "C" void mcu_uart0_rx_irq(void) { eskin::mcu::uart0().on_rx_interrupt(); }
extern "C" void mcu_uart0_tx_irq(void) { eskin::mcu::uart0().on_tx_interrupt(); }
