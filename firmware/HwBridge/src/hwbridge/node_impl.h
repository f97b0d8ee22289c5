// The bodies of node.h: the board's session (PROTOCOL.md 2.5-2.10), following the Python
// reference DeviceSession (protocols/native/_session/). Included by node.h only.
#ifndef HWBRIDGE_NODE_IMPL_H
#define HWBRIDGE_NODE_IMPL_H

#include "node.h"

namespace hwbridge {

/** The control messages as the board reads and writes them, generated from the schema. */
namespace board = control::board;

namespace detail {

/** Copies up to cap bytes of a RAM string; returns the end. */
inline uint8_t* put_str(uint8_t* p, const char* s, size_t cap) {
  while (cap-- && *s) *p++ = static_cast<uint8_t>(*s++);
  return p;
}
/** Copies up to cap bytes of a flash string (generated type names); returns the end. */
inline uint8_t* put_str_P(uint8_t* p, const char* s, size_t cap) {
  uint8_t c;
  while (cap-- && (c = flash_byte(s++)) != 0) *p++ = c;
  return p;
}
/** Element size of a scalar parameter type (strings: 0, they carry their length). */
inline uint8_t param_elem_size(uint8_t scalar) {
  return scalar == kParamBool ? 1 : (scalar == kParamInt32 || scalar == kParamFloat32) ? 4 : 0;
}
inline float f32(const uint8_t* p) {
  const uint32_t v = wire::get32(p);
  float f;
  memcpy(&f, &v, 4);
  return f;
}

}  // namespace detail

// ---------------------------------------------------------------------------------------------
// ParamValue

inline int32_t ParamValue::asInt(uint16_t i) const {
  if (i >= count_) return 0;
  const uint8_t scalar = static_cast<uint8_t>(type & 0x7F);
  if (scalar == kParamBool) return elems_[i];
  if (scalar == kParamInt32) return static_cast<int32_t>(wire::get32(elems_ + 4 * i));
  if (scalar == kParamFloat32) return static_cast<int32_t>(detail::f32(elems_ + 4 * i));
  return 0;
}

inline float ParamValue::asFloat(uint16_t i) const {
  if (i < count_ && (type & 0x7F) == kParamFloat32) return detail::f32(elems_ + 4 * i);
  return static_cast<float>(asInt(i));
}

inline size_t ParamValue::asString(char* out, size_t cap, uint16_t i) const {
  if (cap) out[0] = 0;
  if (i >= count_ || (type & 0x7F) != kParamString) return 0;
  const uint8_t* p = elems_;
  for (uint16_t k = 0; k < i; ++k) p += 2 + wire::get16(p);
  const size_t n = wire::get16(p);
  if (cap) {
    const size_t m = n < cap - 1 ? n : cap - 1;
    memcpy(out, p + 2, m);
    out[m] = 0;
  }
  return n;
}

// ---------------------------------------------------------------------------------------------
// Typed entries

namespace detail {
/**
 * A message on the stack, made by its constructor alone. GCC builds a local `M m;` of a type
 * whose constructor is constexpr (every generated message) from a constant of the whole object:
 * it clears all of it first, every string's N bytes and every array's elements included (a
 * Trigger response's 36 bytes: some 180 cycles on AVR), where the constructor sets a terminator
 * and a size. Through a constructor that is not constexpr, only what M's constructor sets is
 * written.
 */
template <class M>
struct Local : M {
  Local() {}
};

/** Serializes m into buf (cap bytes): false when it does not fit; *n its size. */
template <class M>
bool serialize_into(const M& m, uint8_t* buf, size_t cap, size_t* n) {
  msg::Writer w(buf, cap);
  m.write(w);
  *n = w.finish();
  return w.ok();
}
}  // namespace detail

template <class T>
bool Publisher<T>::publish(const T& msg) {
  size_t cap = 0, n = 0;
  uint8_t* buf = node_ ? node_->txBuffer(&cap) : nullptr;
  if (buf == nullptr || !detail::serialize_into(msg, buf, cap, &n)) return false;
  return node_->sendEntry(*this, n);
}

template <class T>
const char* Publisher<T>::hook(Entry*, uint8_t op, const uint8_t*, size_t*, void*) {
  return op == kOpType ? T::type_name() : reinterpret_cast<const char*>(T::md5_bytes());
}

template <class T>
const char* Subscriber<T>::hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void*) {
  if (op == kOpType) return T::type_name();
  if (op == kOpMd5) return reinterpret_cast<const char*>(T::md5_bytes());
  detail::Local<T> msg;
  if (!msg.deserialize(data, *len)) return "bad";
  static_cast<Subscriber<T>*>(self)->cb_(msg);
  return nullptr;
}

template <class Srv>
const char* ServiceServer<Srv>::hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj) {
  if (op == kOpType) return Srv::type_name();
  if (op == kOpMd5) return reinterpret_cast<const char*>(Srv::md5_bytes());
  detail::Local<Request> req;
  if (!req.deserialize(data, *len)) return "bad request";
  detail::Local<Response> res;
  static_cast<ServiceServer<Srv>*>(self)->cb_(req, res);
  ServiceOut* out = static_cast<ServiceOut*>(obj);
  return detail::serialize_into<Response>(res, out->buf, out->cap, len) ? nullptr : "response too large";
}

template <class Srv>
const char* ServiceClient<Srv>::hook(Entry*, uint8_t op, const uint8_t* data, size_t* len, void* obj) {
  if (op == kOpType) return Srv::type_name();
  if (op == kOpMd5) return reinterpret_cast<const char*>(Srv::md5_bytes());
  return static_cast<Response*>(obj)->deserialize(data, *len) ? nullptr : "bad response";
}

template <class Srv>
uint8_t ServiceClient<Srv>::call(const Request& req, Response& res, uint16_t timeout_ms) {
  size_t cap = 0, n = 0;
  uint8_t* buf = node_ ? node_->txBuffer(&cap) : nullptr;
  if (buf == nullptr || cap < 4 || !detail::serialize_into(req, buf + 4, cap - 4, &n)) {
    return kCallNotConnected;
  }
  return node_->callService(*this, n, timeout_ms, &res);
}

// ---------------------------------------------------------------------------------------------
// NodeHandle_: setup and registration

#define HWB_NODE template <class Hardware, class Profile>
#define HWB_SELF NodeHandle_<Hardware, Profile>

HWB_NODE void HWB_SELF::initNode(uint32_t baud, const char* name, const char* firmware) {
  hw_.init(baud);
  begin(name, firmware);
}

HWB_NODE void HWB_SELF::begin(const char* name, const char* firmware) {
  name_ = name;
  firmware_ = firmware;
  if (!flag(kFixed)) id_ = hw_.seed() | 1u;  // a new random session id (never 0) per boot
  clock();
  be_peer_ = 0;
  be_rx_.resync();
  setFlag(kLead, true);
  state_ = kHandshake;
  teardown();  // the MTUs, a new ISN, the first HELLO now
}

/** Reads the microsecond clock into now_, and the session's ticks of 1.024 ms from it. */
HWB_NODE void HWB_SELF::clock() {
  const Tick before = tick_;
  now_ = hw_.micros();
  // now_ >> 10 from byte moves and a 2-bit shift (a 32-bit shift by 10 is a loop on AVR)
  tick_ = static_cast<Tick>(static_cast<uint16_t>(now_ >> 8) >> 2 |
                            static_cast<uint16_t>(static_cast<uint8_t>(now_ >> 24)) << 14);
  stalled(before, static_cast<typename detail::Pick<detail::SharesCpu<Hardware>::value, detail::SharedCpu,
                                                    detail::OwnCpu>::type*>(nullptr));
}

#if !defined(__AVR__)
/** PROTOCOL.md 2.9's stall rule, for a Hardware that shares the CPU: when more than
 * max(2 x heartbeat, link timeout / 4) = 200 ms passed since the clock was last read, this end
 * was not running (a host program the scheduler left out, a stopped process): only 200 ms of
 * the gap counts as the peer's silence. A peer that really went silent is declared lost a link
 * timeout after this end runs again. */
HWB_NODE void HWB_SELF::stalled(Tick before, detail::SharedCpu*) {
  static const Tick kAwake = ticks(200);
  const Tick step = static_cast<Tick>(tick_ - before);
  if (!established() || step <= kAwake) return;
  last_rx_ = static_cast<Tick>(last_rx_ + (step - kAwake));
  ++stats_.stalls;
}
#endif

HWB_NODE bool HWB_SELF::add(Entry& e) {
  if (e.node_ != nullptr || entry_count_ == 255) return false;
  e.node_ = this;
  e.channel_ = ++entry_count_;
  e.next_ = nullptr;
  Entry** tail = &entries_;
  while (*tail) tail = &(*tail)->next_;
  *tail = &e;
  return true;
}

HWB_NODE Entry* HWB_SELF::entryAt(uint8_t channel) {
  Entry* e = entries_;
  while (e && e->channel_ != channel) e = e->next_;
  return e;
}

HWB_NODE Entry* HWB_SELF::entryOn(uint8_t channel, uint8_t kind) {
  Entry* e = entryAt(channel);
  return e && e->accepted_ && e->kind_ == kind ? e : nullptr;
}

// The rest of the bodies, by responsibility, in this order:
#include "node/loop_output.h"
#include "node/input.h"
#include "node/services_params.h"
#include "node/logs_time.h"

#undef HWB_NODE
#undef HWB_SELF

}  // namespace hwbridge

#endif  // HWBRIDGE_NODE_IMPL_H
