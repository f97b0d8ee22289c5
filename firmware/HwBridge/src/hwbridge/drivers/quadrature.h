// Quadrature wheel encoders on interrupt pins, with a wrapping counter (hwbridge_msgs/WheelTicks).
//
// Pairs with the `diffdrive` device plugin (devices/diffdrive/plugin.py): the host node takes
// signed deltas of the counters modulo 2^counter_bits, so the counters here simply wrap.
//
//   hwbridge::drivers::QuadratureEncoder<2, 4> left;     // A on pin 2, B on pin 4
//   left.begin();                                          // in setup()
//   uint16_t n = left.count();                             // any time, interrupt-safe
//
// Decoding: every edge of A and of B (x4) when both pins have an external interrupt
// (digitalPinToInterrupt), otherwise every edge of A only (x2; B is read in A's interrupt); A
// must have one (or the sketch calls on_edge() from its own pin-change interrupt).
// decoding() says which, so that the robot file's counts_per_rev can match (an Uno has two
// interrupt pins: two wheels there decode x2). Forward is A leading B; begin(true) reverses a
// wheel mounted mirrored. No heap; the state is static per (PinA, PinB) pair, so each pair is
// one encoder.
#ifndef HWBRIDGE_DRIVERS_QUADRATURE_H
#define HWBRIDGE_DRIVERS_QUADRATURE_H

#include "arduino_api.h"
#include <stdint.h>

// On AVR with the Arduino core the interrupt reads the pins' input registers directly.
#if defined(__AVR__) && defined(HWBRIDGE_DRIVERS_HAVE_ARDUINO) && defined(portInputRegister)
#define HWBRIDGE_QUADRATURE_FAST_READ 1
#else
#define HWBRIDGE_QUADRATURE_FAST_READ 0
#endif

namespace hwbridge {
namespace drivers {

/** The change of position from quadrature state `prev` to `cur` (each (A << 1) | B): +1 or -1
    for one step (forward = A leading B), 0 for none, and `skipped` set when both channels
    changed at once (an edge was missed; the step's direction is unknown and it is not
    counted). */
inline int8_t quadrature_step(uint8_t prev, uint8_t cur, bool& skipped) {
  // Gray code to position: 00 -> 0, 01 -> 1, 11 -> 2, 10 -> 3 (B leading counts upwards).
  uint8_t p = static_cast<uint8_t>(prev ^ (prev >> 1));
  uint8_t c = static_cast<uint8_t>(cur ^ (cur >> 1));
  uint8_t d = static_cast<uint8_t>((c - p) & 3U);
  skipped = d == 2;
  return d == 3 ? 1 : (d == 1 ? -1 : 0);
}

/** An encoder on pins PinA and PinB; Count (uint16_t or uint32_t) sets the counter's width. */
template <uint8_t PinA, uint8_t PinB, class Count = uint16_t>
class QuadratureEncoder {
 public:
  /** Pins as inputs with pull-ups, counter to zero, interrupts attached. */
  static void begin(bool reversed = false, bool pullup = true) {
    pinMode(PinA, pullup ? INPUT_PULLUP : INPUT);
    pinMode(PinB, pullup ? INPUT_PULLUP : INPUT);
#if HWBRIDGE_QUADRATURE_FAST_READ
    in_a_ = portInputRegister(digitalPinToPort(PinA));
    in_b_ = portInputRegister(digitalPinToPort(PinB));
    mask_a_ = digitalPinToBitMask(PinA);
    mask_b_ = digitalPinToBitMask(PinB);
#endif
    reversed_ = reversed;
    count_ = 0;
    missed_ = 0;
    state_ = read_state();
    int ia = digitalPinToInterrupt(PinA);
    int ib = digitalPinToInterrupt(PinB);
    attached_ = ia != NOT_AN_INTERRUPT;
    x4_ = attached_ && ib != NOT_AN_INTERRUPT;
    if (attached_) attachInterrupt(ia, &on_edge, CHANGE);
    if (x4_) attachInterrupt(ib, &on_edge, CHANGE);
  }
  /** Interrupts detached (the counter keeps its value). */
  static void end() {
    int ia = digitalPinToInterrupt(PinA);
    int ib = digitalPinToInterrupt(PinB);
    if (attached_) detachInterrupt(ia);
    if (x4_) detachInterrupt(ib);
  }
  /** The counter, read with interrupts held off (a multi-byte read is not atomic on AVR). */
  static Count count() {
    noInterrupts();
    Count value = count_;
    interrupts();
    return value;
  }
  /** Back to zero (the emulated board's reset: counters start again from zero). */
  static void reset() {
    noInterrupts();
    count_ = 0;
    interrupts();
  }
  /** 4 (every edge of both channels), 2 (edges of A only), or 0: A has no external interrupt
      and nothing is counted (call on_edge() from a pin-change interrupt of both pins). */
  static uint8_t decoding() { return x4_ ? 4 : (attached_ ? 2 : 0); }
  /** Width of the counter: WheelTicks.counter_bits. */
  static uint8_t counter_bits() { return static_cast<uint8_t>(sizeof(Count) * 8); }
  /** Transitions where both channels changed between two interrupts (x4 only). */
  static uint16_t missed() {
    noInterrupts();
    uint16_t value = missed_;
    interrupts();
    return value;
  }
  /** The interrupt handler (public so that a sketch may call it from its own pin-change ISR). */
  static void on_edge() {
    uint8_t cur = read_state();
    int8_t step;
    if (x4_) {
      bool skipped;
      step = quadrature_step(state_, cur, skipped);
      if (skipped) ++missed_;
    } else {
      // x2: at an edge of A, A != B means A leads (forward).
      step = ((cur >> 1) ^ cur) & 1U ? 1 : -1;
    }
    state_ = cur;
    if (reversed_) step = static_cast<int8_t>(-step);
    count_ = static_cast<Count>(count_ + static_cast<Count>(step));
  }

 private:
  static uint8_t read_state() {
#if HWBRIDGE_QUADRATURE_FAST_READ
    // The pins' input registers, looked up once in begin(): ~1 us instead of two digitalRead()s.
    return static_cast<uint8_t>(((*in_a_ & mask_a_) ? 2U : 0U) | ((*in_b_ & mask_b_) ? 1U : 0U));
#else
    return static_cast<uint8_t>((digitalRead(PinA) ? 2U : 0U) | (digitalRead(PinB) ? 1U : 0U));
#endif
  }
#if HWBRIDGE_QUADRATURE_FAST_READ
  static volatile uint8_t* in_a_;
  static volatile uint8_t* in_b_;
  static uint8_t mask_a_;
  static uint8_t mask_b_;
#endif
  static volatile Count count_;
  static volatile uint16_t missed_;
  static volatile uint8_t state_;
  static bool reversed_;
  static bool x4_;
  static bool attached_;
};

template <uint8_t A, uint8_t B, class C>
volatile C QuadratureEncoder<A, B, C>::count_ = 0;
template <uint8_t A, uint8_t B, class C>
volatile uint16_t QuadratureEncoder<A, B, C>::missed_ = 0;
template <uint8_t A, uint8_t B, class C>
volatile uint8_t QuadratureEncoder<A, B, C>::state_ = 0;
template <uint8_t A, uint8_t B, class C>
bool QuadratureEncoder<A, B, C>::reversed_ = false;
template <uint8_t A, uint8_t B, class C>
bool QuadratureEncoder<A, B, C>::x4_ = false;
template <uint8_t A, uint8_t B, class C>
bool QuadratureEncoder<A, B, C>::attached_ = false;
#if HWBRIDGE_QUADRATURE_FAST_READ
template <uint8_t A, uint8_t B, class C>
volatile uint8_t* QuadratureEncoder<A, B, C>::in_a_ = nullptr;
template <uint8_t A, uint8_t B, class C>
volatile uint8_t* QuadratureEncoder<A, B, C>::in_b_ = nullptr;
template <uint8_t A, uint8_t B, class C>
uint8_t QuadratureEncoder<A, B, C>::mask_a_ = 0;
template <uint8_t A, uint8_t B, class C>
uint8_t QuadratureEncoder<A, B, C>::mask_b_ = 0;
#endif

/** The two counters of a differential-drive base into a hwbridge_msgs/WheelTicks (any struct
    with int32 `left`, `right` and uint8 `counter_bits`): the unsigned counter values as the
    emulated board sends them (0..65535 for 16 bits; two's complement for 32). */
template <class Left, class Right, class Ticks>
void fill_wheel_ticks(Ticks& msg) {
  msg.left = static_cast<int32_t>(Left::count());
  msg.right = static_cast<int32_t>(Right::count());
  msg.counter_bits = Left::counter_bits();
}

}  // namespace drivers
}  // namespace hwbridge

#endif  // HWBRIDGE_DRIVERS_QUADRATURE_H
