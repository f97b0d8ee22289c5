// A sketch-like translation unit for the ATmega328P: the framing and stream layers wired to
// the UART registers directly (no Arduino core), so that avr-g++ builds every template of the
// library and avr-size shows what they cost. Not a protocol session: it echoes best-effort
// messages back reliably and acknowledges reliable ones.
//
//   avr-g++ -mmcu=atmega328p -std=gnu++11 -Os -flto -fno-exceptions -fno-rtti
//           -I../HwBridge/src [-DPROFILE_COMFORTABLE] avr_core.cpp -o avr_core.elf
//
// Profiles (PROTOCOL.md 2.13): hello world (MTU 64, window 1, no reassembly buffer) and, with
// -DPROFILE_COMFORTABLE, max_message 192 and window 2.
#include <avr/io.h>

#include "HwBridge.h"

using namespace hwbridge;

namespace {

const size_t kMtu = 64;
#ifdef PROFILE_COMFORTABLE
const size_t kMaxMessage = 192;
const size_t kWindow = 2;
#else
const size_t kMaxMessage = 0;  // every message fits one frame: WHOLE frames need no buffer
const size_t kWindow = 1;
#endif

struct Uart {
  void put(uint8_t b) {
    while (!(UCSR0A & (1 << UDRE0))) {
    }
    UDR0 = b;
  }
};

FrameDecoder<kMtu, false> decoder;
Reassembler<kMaxMessage> reassembler;
ReliableSender<kWindow, kMtu> sender;
ReliableReceiver<kWindow, kMtu, 0> receiver;
BestEffortSender be_sender;
BestEffortReceiver be_receiver;
LeadTracker lead;

volatile uint32_t clock_us;  // a timer interrupt would keep it

void handle(const Frame& f, Uart& uart) {
  Message m;
  if (f.type == FrameType::Ack) {
    sender.on_ack(f, clock_us);
  } else if (f.type == FrameType::Reliable) {
    if (receiver.receive(f) == Received::Deliver) {
      reassembler.feed(f, &m);
      Frame held;
      while (receiver.pop(&held)) reassembler.feed(held, &m);
    }
    receiver.write_ack(uart, lead.lead(clock_us));
  } else if (be_receiver.accept(f.seq) && reassembler.feed(f, &m)) {
    sender.send(m.channel, m.data, m.size);
    be_sender.send(uart, m.channel, m.data, m.size, kMtu, lead.lead(clock_us));
  }
}

}  // namespace

int main() {
  UBRR0 = 8;  // 115200 baud at 16 MHz
  UCSR0B = (1 << RXEN0) | (1 << TXEN0);
  Uart uart;
  for (;;) {
    if (UCSR0A & (1 << RXC0)) {
      if (decoder.push(UDR0) == Decoded::Frame) handle(decoder.frame(), uart);
    }
    Frame out;
    while (sender.poll(clock_us, &out)) {
      FrameHeader h = {out.type, out.frag, out.channel, out.seq};
      write_frame(uart, h, out.payload, out.size, nullptr, 0, lead.lead(clock_us));
    }
  }
}
