// The bodies of node.h: the board's session (PROTOCOL.md 2.5-2.10), following the Python
// reference DeviceSession (protocols/native/_session/). Included by node.h only.
#ifndef HWBRIDGE_NODE_IMPL_H
#define HWBRIDGE_NODE_IMPL_H

#include "node.h"

namespace hwbridge {

namespace detail {

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
// little-endian targets (AVR, ARM, x86): the wire order is the memory order, plain copies
inline uint16_t get16(const uint8_t* p) {
  uint16_t v;
  memcpy(&v, p, 2);
  return v;
}
inline uint32_t get32(const uint8_t* p) {
  uint32_t v;
  memcpy(&v, p, 4);
  return v;
}
inline uint8_t* put16(uint8_t* p, uint16_t v) {
  memcpy(p, &v, 2);
  return p + 2;
}
inline uint8_t* put32(uint8_t* p, uint32_t v) {
  memcpy(p, &v, 4);
  return p + 4;
}
#else
inline uint16_t get16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | p[1] << 8); }
inline uint32_t get32(const uint8_t* p) {
  return static_cast<uint32_t>(get16(p)) | static_cast<uint32_t>(get16(p + 2)) << 16;
}
inline uint8_t* put16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
  return p + 2;
}
inline uint8_t* put32(uint8_t* p, uint32_t v) {
  put16(p, static_cast<uint16_t>(v));
  return put16(p + 2, static_cast<uint16_t>(v >> 16));
}
#endif
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
  const uint32_t v = get32(p);
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
  if (scalar == kParamInt32) return static_cast<int32_t>(detail::get32(elems_ + 4 * i));
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
  for (uint16_t k = 0; k < i; ++k) p += 2 + detail::get16(p);
  const size_t n = detail::get16(p);
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
  T msg;
  if (!msg.deserialize(data, *len)) return "bad";
  static_cast<Subscriber<T>*>(self)->cb_(msg);
  return nullptr;
}

template <class Srv>
const char* ServiceServer<Srv>::hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj) {
  if (op == kOpType) return Srv::type_name();
  if (op == kOpMd5) return reinterpret_cast<const char*>(Srv::md5_bytes());
  Request req;
  if (!req.deserialize(data, *len)) return "bad request";
  Response res;
  static_cast<ServiceServer<Srv>*>(self)->cb_(req, res);
  ServiceOut* out = static_cast<ServiceOut*>(obj);
  return detail::serialize_into(res, out->buf, out->cap, len) ? nullptr : "response too large";
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
  now_ = hw_.micros();
  tick_ = static_cast<Tick>(now_ >> 10);
}

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

HWB_NODE Entry* HWB_SELF::entryOn(uint8_t channel, uint8_t kind) {
  for (Entry* e = entries_; e; e = e->next_) {
    if (e->channel_ == channel) return e->accepted_ && e->kind_ == kind ? e : nullptr;
  }
  return nullptr;
}

// ---------------------------------------------------------------------------------------------
// The loop

HWB_NODE void HWB_SELF::spinOnce() {
  processInput();
  runTimers();
}

HWB_NODE void HWB_SELF::processInput() {
  if (state_ == kOff || flag(kInInput)) return;
  setFlag(kInInput, true);
  clock();
  const size_t kBudget = 2 * FrameDecoder<Profile::kMtu, false>::kCapacity + 8;  // bytes read per call
  for (typename detail::Pick<(kBudget < 256), uint8_t, uint16_t>::type budget = kBudget; budget; --budget) {
    const int c = hw_.read();
    if (c < 0) break;
    if (dec_.push(static_cast<uint8_t>(c)) == Decoded::Frame) onFrame(dec_.frame());
  }
  setFlag(kInInput, false);
  flushOut();
}

HWB_NODE void HWB_SELF::runTimers() {
  if (state_ == kOff || flag(kInInput)) return;
  clock();
  if (established()) {
    if (static_cast<Tick>(tick_ - last_rx_) >= kLinkTimeout ||
        (state_ == kConfiguring && static_cast<Tick>(tick_ - timer_) >= kHandshakeTimeout)) {
      ++stats_.link_losses;
      teardown();
    } else {
      pump();  // retransmissions (the retry limit may end the session)
    }
  }
  if (!established()) {  // the handshake, also right after a session ended: a HELLO at once
    if (reached(tick_, timer_)) {
      sendHello();
      timer_ = static_cast<Tick>(tick_ + hello_wait_);
      hello_wait_ = hello_wait_ < kHelloInterval / 2 ? static_cast<uint8_t>(hello_wait_ * 2) : kHelloInterval;
    }
    hw_.flush();
    return;
  }
  if (state_ == kConnected) {
    // set by serviceClient and requestParam, which check their own deadlines
    if (on_response_) on_response_(this, nullptr, kCallTimeout);
    if (on_param_) on_param_(this, nullptr, kParamTimeout);
    if (Profile::kTimeSyncMs && (features_ & 1) && reached(tick_, time_next_)) {
      requestSyncTime();
      time_next_ = static_cast<decltype(time_next_)>(tick_ + kTimeRetry);
    }
  }
  if (static_cast<Tick>(tick_ - last_tx_) >= kHeartbeat) {
    ++stats_.heartbeats_sent;
    const uint8_t hb = 0x02;
    sendControlBe(&hb, 1);
  }
  hw_.flush();
}

HWB_NODE void HWB_SELF::spinFor() {
  setFlag(kInInput, false);
  processInput();
  runTimers();
}

/** Waits (spinning) until the transmit buffer is free, for at most 250 ms. */
HWB_NODE bool HWB_SELF::waitTx() {
  if (txFree()) return true;
  if (flag(kInInput) || !established()) return false;
  clock();
  const Tick until = static_cast<Tick>(tick_ + kHelloInterval);
  while (!txFree() && established()) {
    if (reached(tick_, until)) return false;
    spinFor();
  }
  return txFree();
}

// ---------------------------------------------------------------------------------------------
// Output

HWB_NODE void HWB_SELF::emit(const Frame& f) {
  FrameHeader h;
  h.type = f.type;
  h.frag = f.frag;
  h.channel = f.channel;
  h.seq = f.seq;
  write_frame(hw_, h, f.payload, f.size, nullptr, 0, markTx());
}

/** Records a frame going out now; true when it needs a leading 0x00 (1.3): the first after
 * the link opened or a HELLO, or after 100 ms without sending. */
HWB_NODE bool HWB_SELF::markTx() {
  const bool lead = flag(kLead) || static_cast<Tick>(tick_ - last_tx_) >= kIdle;
  setFlag(kLead, false);
  last_tx_ = tick_;
  return lead;
}

/** One best-effort message (the node's only call of the sender: one copy of it in flash). */
HWB_NODE void HWB_SELF::sendBe(uint8_t channel, const uint8_t* p, size_t n) {
  const bool lead = markTx();
  if (kFragments) {
    be_tx_.send(hw_, channel, p, n, established() ? mtu_ : kMinMtu, lead);
    return;
  }
  // a board that never fragments: one WHOLE frame (sendOn refused anything above the MTU)
  FrameHeader h;
  h.type = FrameType::BestEffort;
  h.frag = Frag::Whole;
  h.channel = channel;
  h.seq = be_tx_.take();
  write_frame(hw_, h, p, n, nullptr, 0, lead);
}

HWB_NODE void HWB_SELF::sendHello() {
  ++stats_.hellos_sent;
  uint8_t h[21];
  h[0] = 0x01;
  h[1] = 1;  // version
  h[2] = 1;  // role: board
  h[3] = established() ? 1 : 0;
  detail::put32(h + 4, id_);
  detail::put32(h + 8, peer_);
  detail::put16(h + 12, Profile::kMtu);
  detail::put32(h + 14, Profile::kMaxMessage);
  h[18] = Profile::kWindow;
  h[19] = isn_;
  h[20] = Profile::kFeatures;
  setFlag(kLead, true);  // 1.3: a HELLO is always led by 0x00
  sendControlBe(h, 21);
}

/** After input: the ACK that is due (every one at once: this board never holds ACKs back),
 * then what the reliable window lets out. */
HWB_NODE void HWB_SELF::flushOut() {
  if (established() && rel_rx_.ack_needed()) {
    rel_rx_.write_ack(hw_, markTx());
  }
  pump();
  hw_.flush();
}

/** Moves the waiting message (or the next table message) into the reliable window and sends
 * every frame that is due. */
HWB_NODE void HWB_SELF::pump() {
  if (!established()) return;
  while (!rel_tx_.sending() && rel_tx_.free_slots()) {
    if (pending_len_ == 0 && !queueTable()) break;
    if (!rel_tx_.send(pending_ch_, tx_, pending_len_)) break;
    pending_len_ = 0;
  }
  Frame f;
  while (rel_tx_.poll(RelTx::kTicks ? tick_ : now_, &f)) emit(f);
  if (rel_tx_.dead()) {
    ++stats_.link_losses;
    teardown();
  }
}

/** Builds the next message of the topic table (2.6) in tx_; false when the table is done. */
HWB_NODE bool HWB_SELF::queueTable() {
  if (state_ != kConfiguring || table_pos_ > entry_count_ + 1) return false;
  uint8_t* p = tx_;
  const size_t cap = Profile::kTxBuffer;
  static_assert(Profile::kTxBuffer >= 24, "kTxBuffer must hold at least 24 bytes");
  if (table_pos_ == 0) {  // BOARD_INFO
    *p++ = 0x10;
    *p++ = entry_count_;
    uint8_t* len = p++;
    p = detail::put_str(p, name_, cap - 5 < 255 ? cap - 5 : 255);
    *len = static_cast<uint8_t>(p - len - 1);
    const size_t room = cap - static_cast<size_t>(p - tx_) - 1;
    const uint8_t ul = uid_len_ <= room ? uid_len_ : static_cast<uint8_t>(room);
    *p++ = ul;
    if (ul) memcpy(p, uid_, ul);  // uid_ may be null when ul is 0
    p += ul;
    p = detail::put_str(p, firmware_, cap - static_cast<size_t>(p - tx_));
  } else if (table_pos_ <= entry_count_) {  // TOPIC
    Entry* e = entries_;
    for (uint8_t i = 1; i < table_pos_; ++i) e = e->next_;
    *p++ = 0x11;
    *p++ = e->channel_;
    *p++ = e->kind_;
    *p++ = e->reliable_ ? 1 : 0;
    flash_copy(p, e->hook_(e, Entry::kOpMd5, nullptr, nullptr, nullptr), 16);
    p += 16;
    uint8_t* len = p++;
    p = detail::put_str(p, e->name_, cap - 21);
    *len = static_cast<uint8_t>(p - len - 1);
    p = detail::put_str_P(p, e->hook_(e, Entry::kOpType, nullptr, nullptr, nullptr),
                          cap - static_cast<size_t>(p - tx_));
  } else {  // TABLE_END
    *p++ = 0x12;
    *p++ = entry_count_;
  }
  ++table_pos_;
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(p - tx_);
  return true;
}

// ---------------------------------------------------------------------------------------------
// Input

HWB_NODE void HWB_SELF::onFrame(const Frame& f) {
  if (f.type == FrameType::BestEffort) {
    onBestEffort(f);
    return;
  }
  if (!established()) {
    ++stats_.ignored_frames;
    return;
  }
  last_rx_ = tick_;
  if (f.type == FrameType::Ack) {
    rel_tx_.on_ack(f, now_);
    return;
  }
  if (rel_rx_.receive(f) != Received::Deliver) return;
  deliver(f);
  // frames held early (a window above 1) that are now in order; a teardown in onMessage
  // empties the receiver, which ends this
  Frame h;
  while (rel_rx_.pop(&h)) deliver(h);
}

/** A frame its stream accepted: through reassembly to onMessage. */
HWB_NODE void HWB_SELF::deliver(const Frame& f) {
  Message m;
  if (reasm_.feed(f, &m)) onMessage(m, f.type == FrameType::Reliable);
}

HWB_NODE void HWB_SELF::onBestEffort(const Frame& f) {
  const uint8_t* p = f.payload;
  if (f.channel == kControlChannel && f.size >= 8 && p[0] == 0x01 && p[1] == 1) {
    const uint32_t peer = detail::get32(p + 4);  // a HELLO: a new session has its own seq space
    if (peer != be_peer_ && peer != id_) {
      be_peer_ = peer;
      be_rx_.resync();
      reasm_.reset(FrameType::BestEffort);
    }
  }
  if (be_rx_.accept(f.seq)) deliver(f);
}

HWB_NODE void HWB_SELF::onMessage(const Message& m, bool reliable) {
  if (m.channel == kControlChannel) {
    onControl(m.data, m.size, reliable);
  } else if (established()) {
    last_rx_ = tick_;
    if (on_data_) {
      on_data_(this, m);
    } else {  // this board subscribes to nothing
      ++stats_.dropped_messages;
    }
  } else {
    ++stats_.ignored_frames;
  }
}

HWB_NODE void HWB_SELF::onData(const Message& m) {
  Entry* e = state_ == kConnected ? entryOn(m.channel, kSubscriber) : nullptr;
  size_t len = m.size;
  if (e == nullptr || e->hook_(e, Entry::kOpDeliver, m.data, &len, nullptr) != nullptr) {
    ++stats_.dropped_messages;
  }
}

HWB_NODE void HWB_SELF::onControl(const uint8_t* p, size_t n, bool reliable) {
  // the fixed size of each opcode's fields (0: unknown); variable ones give their minimum
  static const uint8_t kBe[8] HWBRIDGE_PROGMEM = {0, 21, 1, 0, 21, 1, 9, 0};  // opcodes 0x00..0x07 (board's view)
  if (n == 0) {
    protocolError();
    return;
  }
  const uint8_t op = p[0];
  uint8_t need = 0;
  if (op < 8) {
    need = flash_byte(reinterpret_cast<const char*>(kBe) + op);
  } else if (op == 0x13) {
    need = 3;
  } else if (op == 0x14) {
    need = 2;
  } else if (op == 0x20) {
    need = 4;
  } else if (op == 0x21) {
    need = 5;
  } else if (op == 0x31) {
    need = 5;
  } else if (op == 0x40) {
    need = 2;
  }
  if (need == 0 || n < need || (op < 0x10) == reliable) {  // unknown, short, or wrong stream
    protocolError();
    return;
  }
  if (op == 0x01) {
    onHello(p);
    return;
  }
  if (!established()) {
    ++stats_.ignored_frames;
    return;
  }
  last_rx_ = tick_;
  switch (op) {
    case 0x02:  // HEARTBEAT
      break;
    case 0x04:  // TIME_RESPONSE: only a board that asks (kTimeSyncMs) reads the answers
      if (Profile::kTimeSyncMs) onTimeResponse(p);
      break;
    case 0x05:  // GOODBYE
      ++stats_.peer_resets;
      teardown();
      break;
    case 0x06: {  // HOST_TIME_REQUEST: t1 echoed, t2 = t3 = now
      if (!(Profile::kFeatures & 1)) break;
      if (!flag(kTimeSynced)) {  // a first estimate of host time: t1 plus the one-way delay
        host_sec_ = detail::get32(p + 1);
        host_nsec_ = detail::get32(p + 5);
        board_ref_ = now_;
      }
      uint8_t r[17];
      r[0] = 0x07;
      memcpy(r + 1, p + 1, 8);
      detail::put32(r + 9, now_);
      detail::put32(r + 13, now_);
      sendControlBe(r, 17);
      break;
    }
    case 0x13:
      onTopicAck(p, n);
      break;
    case 0x14:  // READY
      if (state_ != kConfiguring) break;
      {
        uint8_t accepted = 0;
        for (Entry* e = entries_; e; e = e->next_) accepted = static_cast<uint8_t>(accepted + e->accepted_);
        if (accepted != p[1]) protocolError();
      }
      state_ = kConnected;
      time_next_ = static_cast<decltype(time_next_)>(tick_);
      break;
    case 0x20:
      if (on_request_) {
        on_request_(this, p, n);
      } else if (txFree()) {  // this board serves nothing: NO_SERVICE
        memcpy(tx_, p, 4);
        tx_[0] = 0x21;
        tx_[4] = 2;
        pending_ch_ = kControlChannel;
        pending_len_ = 5;
      }
      break;
    case 0x21:  // SERVICE_RESPONSE: only to a board with a service client
      if (on_response_ && p[4] <= 2) {
        on_response_(this, p, n);
      } else {
        protocolError();
      }
      break;
    case 0x31:
      if (on_param_) {
        on_param_(this, p, n);
      } else {  // this board asked for no parameter
        protocolError();
      }
      break;
    case 0x40:  // LOG from the host: never sent to a board without HOST_LOG (4) in its features
      if (!(Profile::kFeatures & 4) || p[1] > 4) {
        protocolError();
      } else if (log_cb_ != nullptr) {
        log_cb_(p[1], reinterpret_cast<const char*>(p + 2), n - 2);
      }
      break;
    default:  // an opcode only a board sends
      protocolError();
  }
}

HWB_NODE void HWB_SELF::onHello(const uint8_t* p) {
  const uint32_t session = detail::get32(p + 4);
  const uint32_t peer_session = detail::get32(p + 8);
  if (p[1] != 1 || p[2] != 0) {  // another version, or the peer is a board (or an echo)
    protocolError();
    return;
  }
  if (established() && (session != peer_ || peer_session != id_)) {
    ++stats_.peer_resets;  // the host restarted, or dropped the session
    teardown();
  }
  if (!established()) {
    if (detail::get16(p + 12) < (kFragments ? kMinMtu : Profile::kTxBuffer) || p[18] == 0 || detail::get32(p + 14) == 0 || session == 0) {
      protocolError();
      return;
    }
    peer_ = session;
    if (peer_session == id_) establish(p);
  }
  if (!(p[3] & 1)) sendHello();
}

HWB_NODE void HWB_SELF::establish(const uint8_t* h) {
  const uint16_t host_mtu = detail::get16(h + 12);
  mtu_ = kFixedMtu || host_mtu > Profile::kMtu ? Profile::kMtu : host_mtu;
  // the host's window is at least 1 (onHello refused 0)
  uint8_t window = Profile::kWindow == 1 || h[18] > Profile::kWindow ? Profile::kWindow : h[18];
  if (window > kMaxWindow) window = kMaxWindow;
  const uint32_t peer_max = detail::get32(h + 14);
  peer_max_ = peer_max > 0xFFFFUL ? 0xFFFFu : static_cast<uint16_t>(peer_max);
  features_ = static_cast<uint8_t>(h[20] & Profile::kFeatures);
  rel_tx_.reset(isn_, window, kFixedMtu ? Profile::kMtu : mtu_);
  rel_rx_.reset(h[19], window);
  reasm_.reset(FrameType::Reliable);
  // the receiver's limit becomes the negotiated MTU (2.5); for a board that does not fragment
  // and whose largest message fills its MTU, that is always its own (smaller host MTUs refused)
  if (!kFixedMtu) dec_.set_max_payload(mtu_);
  // every entry is unaccepted: teardown cleared them, and only a session accepts one
  table_pos_ = 0;
  pending_len_ = 0;
  state_ = kConfiguring;
  timer_ = last_rx_ = tick_;
  ++stats_.sessions;
}

/** Ends the session (2.10), or starts the first handshake: pending requests fail, the reliable
 * stream is dropped, a new ISN is drawn, and a HELLO goes out at the next timer run. */
HWB_NODE void HWB_SELF::teardown() {
  const bool was = established();
  state_ = kHandshake;
  peer_ = 0;
  peer_max_ = kMinMtu;
  mtu_ = Profile::kMtu;
  if (!kFixedMtu) dec_.set_max_payload(Profile::kMtu);
  if (was) reasm_.reset(FrameType::Reliable);
  pending_len_ = 0;
  setFlag(kTimeSynced, false);
  features_ = 0;
  // a new ISN per session: the random session id mixed with the time (no generator state kept)
  isn_ = flag(kFixed) ? fixed_isn_ : static_cast<uint8_t>(id_ ^ now_ ^ now_ >> 8);
  rel_tx_.reset(isn_, Profile::kWindow, Profile::kMtu);
  timer_ = tick_;
  hello_wait_ = kHelloFirst;
  for (Entry* e = entries_; e; e = e->next_) e->accepted_ = false;
  // through the pointers serviceClient and requestParam set: a sketch without service clients
  // or parameters links none of it
  if (on_response_) on_response_(this, nullptr, kCallSessionReset);
  if (on_param_) on_param_(this, nullptr, kParamSessionReset);
}

HWB_NODE void HWB_SELF::onTopicAck(const uint8_t* p, size_t n) {
  const uint8_t status = p[2];
  Entry* e = entries_;
  while (e && e->channel_ != p[1]) e = e->next_;
  if (e == nullptr || status > 2 || (status != 0 && n < 19)) {
    protocolError();
    return;
  }
  if (status == 0) {
    e->accepted_ = true;
    return;
  }
  protocolError();
  if (status == 1) {
    ++stats_.mismatches;
  } else {
    ++stats_.refused_entries;
  }
}

// ---------------------------------------------------------------------------------------------
// Services

HWB_NODE void HWB_SELF::onServiceRequest(const uint8_t* p, size_t n) {
  const uint8_t channel = p[1];
  const uint16_t id = detail::get16(p + 2);
  if (!txFree()) {  // no room to answer now: the host's call times out
    ++stats_.tx_refused;
    return;
  }
  Entry* e = state_ == kConnected ? entryOn(channel, kServiceServer) : nullptr;
  uint8_t status = 2;  // NO_SERVICE
  size_t len = 0;
  if (e != nullptr) {
    const size_t cap = Profile::kTxBuffer - 5;
    const size_t limit = static_cast<size_t>(peer_max_) - 5 < cap ? static_cast<size_t>(peer_max_) - 5 : cap;
    ServiceOut out = {tx_ + 5, limit};
    len = n - 4;
    const char* err = e->hook_(e, Entry::kOpDeliver, p + 4, &len, &out);
    status = 0;
    if (err != nullptr) {
      status = 1;  // ERROR, with the reason as the body
      uint8_t* end = detail::put_str(tx_ + 5, err, limit);
      len = static_cast<size_t>(end - tx_ - 5);
    }
  }
  tx_[0] = 0x21;
  tx_[1] = channel;
  detail::put16(tx_ + 2, id);
  tx_[4] = status;
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(5 + len);
}

HWB_NODE void HWB_SELF::onServiceResponse(const uint8_t* p, size_t n) {
  if (call_state_ != 1 || detail::get16(p + 2) != call_id_ || call_entry_ == nullptr ||
      p[1] != call_entry_->channel_) {
    return;  // late, or not ours
  }
  call_status_ = p[4];
  if (call_status_ == kCallOk) {
    size_t len = n - 5;
    if (call_entry_->hook_(call_entry_, Entry::kOpDeliver, p + 5, &len, call_res_) != nullptr) {
      call_status_ = kCallBadResponse;
    }
  }
  call_state_ = 2;
}

HWB_NODE uint8_t HWB_SELF::call(Entry& e, size_t len, uint16_t timeout_ms, void* res) {
  if (state_ != kConnected || !e.accepted_ || call_state_ == 1 || flag(kInInput) ||
      len + 4 > peer_max_) {
    ++stats_.tx_refused;
    return kCallNotConnected;
  }
  call_id_ = newRequestId();
  tx_[0] = 0x20;
  tx_[1] = e.channel_;
  detail::put16(tx_ + 2, call_id_);
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(len + 4);
  call_entry_ = &e;
  call_res_ = res;
  call_state_ = 1;
  clock();
  timer_ = static_cast<Tick>(tick_ + msTicks(timeout_ms ? timeout_ms : Profile::kServiceTimeoutMs));
  pump();
  hw_.flush();
  while (call_state_ == 1) spinFor();
  call_state_ = 0;
  call_entry_ = nullptr;
  return call_status_;
}

HWB_NODE uint16_t HWB_SELF::newRequestId() {
  uint16_t id;
  do {
    id = ++next_request_;
  } while (id == 0 || id == param_id_ || (call_state_ == 1 && id == call_id_));
  return id;
}

// ---------------------------------------------------------------------------------------------
// Parameters

HWB_NODE uint16_t HWB_SELF::requestParam(const char* name, uint8_t type, ParamCallback cb,
                                          bool subscribe, uint16_t max_count) {
  const size_t len = strlen(name);
  param_cb_ = cb;
  if (param_id_ || state_ != kConnected || !waitTx() || len + 7 > Profile::kTxBuffer ||
      len + 7 > peer_max_) {
    ++stats_.tx_refused;
    ParamValue v;
    memset(&v, 0, sizeof(v));
    v.status = kParamNotConnected;
    if (cb) cb(v);
    return 0;
  }
  on_param_ = &paramThunk;
  param_id_ = newRequestId();
  if (subscribe) push_cb_ = cb;
  uint8_t* p = tx_;
  *p++ = 0x30;
  p = detail::put16(p, param_id_);
  *p++ = type;
  *p++ = subscribe ? 1 : 0;
  p = detail::put16(p, max_count);
  memcpy(p, name, len);
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(7 + len);
  param_deadline_ = static_cast<Tick>(tick_ + ticks(Profile::kParamTimeoutMs));
  pump();
  hw_.flush();
  return param_id_;
}

HWB_NODE void HWB_SELF::finishParam(uint8_t status, const ParamValue* v) {
  ParamValue none;
  if (v == nullptr) {
    memset(&none, 0, sizeof(none));
    none.request_id = param_id_;
    none.status = status;
    v = &none;
  }
  param_id_ = 0;
  if (sync_state_ == 1) {  // a blocking getParam: copy the values out
    sync_state_ = v->status == kParamOk && sync_copy_(sync_out_, *v, sync_len_) ? 2 : 3;
    return;
  }
  if (param_cb_) param_cb_(*v);
}

HWB_NODE void HWB_SELF::onParamValue(const uint8_t* p, size_t n) {
  ParamValue v;
  v.request_id = detail::get16(p + 1);
  v.status = p[3];
  v.name_len = p[4];
  v.name = reinterpret_cast<const char*>(p + 5);
  v.type = 0;
  v.count_ = 0;
  v.elems_ = nullptr;
  v.size_ = 0;
  size_t at = 5u + v.name_len;
  bool good = v.status <= 3 && at <= n;
  if (good && v.status == kParamOk) {
    good = at < n;
    if (good) {
      v.type = p[at++];
      const uint8_t scalar = static_cast<uint8_t>(v.type & 0x7F);
      good = scalar >= 1 && scalar <= 4 && (v.type & 0x80 ? at + 2 <= n : true);
      if (good) {
        v.count_ = 1;
        if (v.type & 0x80) {
          v.count_ = detail::get16(p + at);
          at += 2;
        }
        v.elems_ = p + at;
        const uint8_t es = detail::param_elem_size(scalar);
        for (uint16_t i = 0; good && i < v.count_; ++i) {  // every element within the payload
          size_t step = es;
          if (es == 0) step = at + 2 <= n ? 2u + detail::get16(p + at) : n + 1;
          good = at + step <= n;
          at += step;
        }
        v.size_ = at - static_cast<size_t>(v.elems_ - p);
      }
    }
  }
  if (!good) {
    protocolError();
    return;
  }
  if (v.request_id == 0) {  // pushed: a subscribed parameter changed
    if (v.status == kParamOk && push_cb_) push_cb_(v);
    return;
  }
  if (v.request_id != param_id_) return;  // answered after its timeout
  finishParam(v.status, &v);
}

HWB_NODE bool HWB_SELF::blockingParam(const char* name, uint8_t type, void* out, uint16_t length,
                                       uint16_t timeout_ms,
                                       bool (*copy)(void*, const ParamValue&, uint16_t)) {
  if (flag(kInInput) || param_id_ || length == 0) return false;
  sync_out_ = out;
  sync_copy_ = copy;
  sync_len_ = length;
  sync_state_ = 1;
  const bool list = length > 1 && type != kParamString;
  if (requestParam(name, static_cast<uint8_t>(list ? (type | kParamList) : type), nullptr, false,
                   list ? length : 0) == 0) {
    sync_state_ = 0;
    return false;
  }
  if (timeout_ms) param_deadline_ = static_cast<Tick>(tick_ + msTicks(timeout_ms));
  while (sync_state_ == 1) spinFor();
  const bool ok = sync_state_ == 2;
  sync_state_ = 0;
  return ok;
}

namespace detail {
template <class V>
bool copy_values(void* out, const ParamValue& v, uint16_t n);
template <>
inline bool copy_values<int32_t>(void* out, const ParamValue& v, uint16_t n) {
  if (v.count() != n || (v.type & 0x7F) == kParamString) return false;
  for (uint16_t i = 0; i < n; ++i) static_cast<int32_t*>(out)[i] = v.asInt(i);
  return true;
}
template <>
inline bool copy_values<float>(void* out, const ParamValue& v, uint16_t n) {
  if (v.count() != n || (v.type & 0x7F) == kParamString) return false;
  for (uint16_t i = 0; i < n; ++i) static_cast<float*>(out)[i] = v.asFloat(i);
  return true;
}
template <>
inline bool copy_values<bool>(void* out, const ParamValue& v, uint16_t n) {
  if (v.count() != n || (v.type & 0x7F) == kParamString) return false;
  for (uint16_t i = 0; i < n; ++i) static_cast<bool*>(out)[i] = v.asBool(i);
  return true;
}
template <>
inline bool copy_values<char>(void* out, const ParamValue& v, uint16_t cap) {
  if (v.count() != 1 || (v.type & 0x7F) != kParamString) return false;
  v.asString(static_cast<char*>(out), cap);
  return true;
}
}  // namespace detail

HWB_NODE bool HWB_SELF::getParamString(const char* name, char* out, size_t cap, uint16_t timeout_ms) {
  if (cap == 0) return false;
  out[0] = 0;
  return blockingParam(name, kParamString, out, static_cast<uint16_t>(cap > 0xFFFF ? 0xFFFF : cap),
                       timeout_ms, &detail::copy_values<char>);
}

HWB_NODE bool HWB_SELF::getParam(const char* name, int32_t* value, uint16_t length, uint16_t timeout_ms) {
  return blockingParam(name, kParamInt32, value, length, timeout_ms, &detail::copy_values<int32_t>);
}
HWB_NODE bool HWB_SELF::getParam(const char* name, float* value, uint16_t length, uint16_t timeout_ms) {
  return blockingParam(name, kParamFloat32, value, length, timeout_ms, &detail::copy_values<float>);
}
HWB_NODE bool HWB_SELF::getParam(const char* name, bool* value, uint16_t length, uint16_t timeout_ms) {
  return blockingParam(name, kParamBool, value, length, timeout_ms, &detail::copy_values<bool>);
}

// ---------------------------------------------------------------------------------------------
// Logs, time, publishing

HWB_NODE bool HWB_SELF::log(uint8_t level, const char* text) {
  if (state_ != kConnected || !waitTx()) {
    ++stats_.tx_refused;
    return false;
  }
  const size_t cap = Profile::kTxBuffer < peer_max_ ? Profile::kTxBuffer : peer_max_;
  tx_[0] = 0x40;
  tx_[1] = level;
  size_t n = static_cast<size_t>(detail::put_str(tx_ + 2, text, cap - 2) - tx_ - 2);
  while (n && (static_cast<uint8_t>(text[n]) & 0xC0) == 0x80) --n;  // cut on a UTF-8 boundary
  uint8_t* end = tx_ + 2 + n;
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(end - tx_);
  pump();
  hw_.flush();
  return true;
}

HWB_NODE void HWB_SELF::requestSyncTime() {
  if (state_ != kConnected || !(features_ & 1)) return;
  uint8_t r[5];
  r[0] = 0x03;
  detail::put32(r + 1, now_);
  sendControlBe(r, 5);
}

HWB_NODE void HWB_SELF::onTimeResponse(const uint8_t* p) {
  const uint32_t elapsed = now_ - detail::get32(p + 1);
  if (elapsed > kMaxTimeAgeUs) return;
  const uint32_t t2s = detail::get32(p + 5), t2n = detail::get32(p + 9);
  const uint32_t t3s = detail::get32(p + 13), t3n = detail::get32(p + 17);
  const uint32_t busy_s = t3s - t2s;
  if (busy_s > 10 || t2n >= 1000000000UL || t3n >= 1000000000UL) return;  // nonsense: ignored
  // host busy time t3 - t2 in us
  const int32_t busy = static_cast<int32_t>(busy_s) * 1000000L +
                       (static_cast<int32_t>(t3n) - static_cast<int32_t>(t2n)) / 1000;
  int32_t rtt = static_cast<int32_t>(elapsed) - busy;
  if (rtt < 0) rtt = 0;
  // reference pair: board_ref = t4 (now), host_ref = t3 + rtt / 2
  host_sec_ = t3s;
  host_nsec_ = t3n + static_cast<uint32_t>(rtt / 2) * 1000u;
  while (host_nsec_ >= 1000000000UL) {
    host_nsec_ -= 1000000000UL;
    ++host_sec_;
  }
  board_ref_ = now_;
  setFlag(kTimeSynced, true);
  time_next_ = static_cast<decltype(time_next_)>(tick_ + ticks(Profile::kTimeSyncMs));
}

HWB_NODE void HWB_SELF::now(uint32_t* sec, uint32_t* nsec) {
  if (host_sec_ == 0 && host_nsec_ == 0) {
    *sec = *nsec = 0;
    return;
  }
  const uint32_t us = hw_.micros() - board_ref_;
  const uint32_t whole = us / 1000000UL;
  uint32_t ns = host_nsec_ + (us - whole * 1000000UL) * 1000UL;
  uint32_t s = host_sec_ + whole;
  if (ns >= 1000000000UL) {
    ns -= 1000000000UL;
    ++s;
  }
  *sec = s;
  *nsec = ns;
}

HWB_NODE uint8_t* HWB_SELF::takeTxBuffer(size_t* cap) {
  *cap = Profile::kTxBuffer;
  if (state_ != kConnected || !waitTx()) {
    ++stats_.tx_refused;
    return nullptr;
  }
  return tx_;
}

HWB_NODE bool HWB_SELF::sendOn(Entry& e, size_t len) {
  if (state_ != kConnected || !e.accepted_ || len > peer_max_ || !txFree() || (!kFragments && !kFixedMtu && len > mtu_)) {
    ++stats_.tx_refused;
    return false;
  }
  if (e.reliable_) {
    pending_ch_ = e.channel_;
    pending_len_ = static_cast<uint16_t>(len);
    pump();
  } else {
    clock();
    sendBe(e.channel_, tx_, len);
  }
  hw_.flush();
  return true;
}

#undef HWB_NODE
#undef HWB_SELF

}  // namespace hwbridge

#endif  // HWBRIDGE_NODE_IMPL_H
