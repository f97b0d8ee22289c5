// The bodies of NodeHandle_, part of node_impl.h: services (server and client) and parameters.
// Included inside namespace hwbridge by node_impl.h only, which defines HWB_NODE and HWB_SELF.
#ifndef HWBRIDGE_NODE_SERVICES_PARAMS_H
#define HWBRIDGE_NODE_SERVICES_PARAMS_H
#ifndef HWB_NODE
#error "hwbridge/node/*.h are parts of node_impl.h: include HwBridge.h"
#endif

// ---------------------------------------------------------------------------------------------
// Services

/** A request with this id for the server on channel, its body n bytes at body. With
 * SERVICE_CHANNELS (2.8) the answer goes on that channel if it is a server's (with SHORT_CALLS
 * too, its head is one byte), else (also NO_SERVICE to a SERVICE_REQUEST for another channel,
 * or in a SHORT_CALLS session to one whose id does not fit in 7 bits) as a SERVICE_RESPONSE on
 * channel 0. */
HWB_NODE void HWB_SELF::onServiceRequest(uint8_t channel, uint16_t id, const uint8_t* body_in, size_t n) {
  Entry* e = entryAt(channel);
  const bool brief = shortCalls();
  if (e != nullptr && (e->kind_ != kServiceServer || (brief && id > kShortIdMask))) e = nullptr;
  const bool own = e != nullptr && (features_ & control::Features::SERVICE_CHANNELS) != 0;
  const bool short_head = own && brief;
  const size_t head = short_head ? 1 : own ? kAnswerHead : board::ServiceResponse::kBody;
  if (peer_max_ < head) {  // no room to answer, ever: the host's call times out
    ++stats_.tx_refused;
    return;
  }
  if (state_ != kConnected || (e != nullptr && !e->accepted_)) e = nullptr;
  // The answer is built in the reliable sender's slot when it is free (a window of one frame:
  // SingleFrameSender::kInPlace; no copy before it goes out), else in tx_ to wait for the
  // window (admitRequest made sure tx_ is free); either holds kTxBuffer bytes. Its head first
  // (the status, its last byte, once known): less to keep across the service's callback.
  static_assert(!RelTx::kInPlace || Profile::kTxBuffer <= Profile::kMtu, "the slot holds kMtu bytes");
  const bool in_slot = RelTx::kInPlace && rel_tx_.free_slots() != 0;
  uint8_t* const msg = in_slot ? rel_tx_.slot() : tx_;
  uint8_t ch = kControlChannel;
  if (own) {
    wire::put16(msg, id);  // (a short head is the low byte: the body overwrites the other)
    ch = channel;
  } else {
    board::ServiceResponse::put(msg, channel, id, 0);
  }
  uint8_t* const body = msg + head;
  uint8_t status = control::ServiceStatus::NO_SERVICE;
  size_t len = short_head;  // (NO_SERVICE with a short head: the status is the body)
  if (e != nullptr) {
    // (commit() skips send()'s MTU check: a board that does not fragment, the one-slot
    // sender's, refuses a host whose MTU is below its own, so kTxBuffer <= kMtu <= the link's)
    const size_t cap = Profile::kTxBuffer - head;
    const size_t limit = static_cast<size_t>(peer_max_) - head < cap ? static_cast<size_t>(peer_max_) - head : cap;
    ServiceOut out = {body, limit};
    len = n;
    const char* err = e->hook_(e, Entry::kOpDeliver, body_in, &len, &out);
    status = control::ServiceStatus::OK;
    if (err != nullptr) {
      status = control::ServiceStatus::ERROR;  // with the reason as the body
      // (a short head takes the status as the body's first byte: the text after it)
      len = static_cast<size_t>(detail::put_str(body + short_head, err, limit - short_head) - body);
    }
  }
  if (!short_head) {
    body[-1] = status;  // the head's last byte in both long forms (SERVICE_RESPONSE: p[4] of 5)
  } else if (status != control::ServiceStatus::OK) {
    msg[0] |= kStatusFollows;  // id | 0x80, then the status (2.8)
    body[0] = status;
  }
  if (in_slot) {
    rel_tx_.commit(ch, head + len);
  } else {
    pending_ch_ = ch;
    pending_len_ = static_cast<uint16_t>(head + len);
  }
}

/** The response to the pending call, on its entry's channel: its request id and status, and
 * its body (n bytes at body). */
HWB_NODE void HWB_SELF::onServiceResponse(uint16_t id, uint8_t status, const uint8_t* body, size_t n) {
  if (call_state_ != 1 || id != call_id_) return;  // late, or not ours
  call_status_ = status;
  if (call_status_ == kCallOk) {
    size_t len = n;
    if (call_entry_->hook_(call_entry_, Entry::kOpDeliver, body, &len, call_res_) != nullptr) {
      call_status_ = kCallBadResponse;
    }
  }
  call_state_ = 2;
}

HWB_NODE uint8_t HWB_SELF::call(Entry& e, size_t len, uint16_t timeout_ms, void* res) {
  // the request was serialized after room for SERVICE_REQUEST's opcode, channel and id; on the
  // service's own channel (SERVICE_CHANNELS, 2.8) the id alone comes before it, in one byte with
  // SHORT_CALLS (every id of this board fits: newRequestId)
  const bool own = (features_ & control::Features::SERVICE_CHANNELS) != 0;
  const bool short_head = shortCalls();
  const size_t head = short_head ? 1 : own ? kCallHead : board::ServiceRequest::kBody;
  if (state_ != kConnected || !e.accepted_ || call_state_ == 1 || flag(kInInput) ||
      len + head > peer_max_) {
    ++stats_.tx_refused;
    return kCallNotConnected;
  }
  call_id_ = newRequestId();
  if (own) {
    memmove(tx_ + head, tx_ + board::ServiceRequest::kBody, len);
    if (short_head) {
      tx_[0] = static_cast<uint8_t>(call_id_);
    } else {
      wire::put16(tx_, call_id_);
    }
    pending_ch_ = e.channel_;
  } else {
    board::ServiceRequest::put(tx_, e.channel_, call_id_);
    pending_ch_ = kControlChannel;
  }
  pending_len_ = static_cast<uint16_t>(len + head);
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

/** The next request id, for a call or a parameter: 1..127 (a valid id in every form, the
 * one-byte head of SHORT_CALLS too), none that a pending request holds. */
HWB_NODE uint16_t HWB_SELF::newRequestId() {
  uint16_t id;
  do {
    id = static_cast<uint8_t>(++next_request_ & kShortIdMask);
  } while (id == 0 || id == param_id_ || (call_state_ == 1 && id == call_id_));
  return id;
}

// ---------------------------------------------------------------------------------------------
// Parameters

HWB_NODE uint16_t HWB_SELF::requestParam(const char* name, uint8_t type, ParamCallback cb,
                                          bool subscribe, uint16_t max_count) {
  clock();  // the deadline counts from now
  const size_t len = strlen(name);
  if (param_id_ || state_ != kConnected || !waitTx() || len + 7 > Profile::kTxBuffer ||
      len + 7 > peer_max_) {
    ++stats_.tx_refused;
    ParamValue v;
    memset(&v, 0, sizeof(v));
    v.status = kParamNotConnected;
    if (cb) cb(v);  // the pending request (if any) keeps its own callback
    return 0;
  }
  param_cb_ = cb;
  on_param_ = &paramThunk;
  param_id_ = newRequestId();
  if (subscribe) push_cb_ = cb;
  uint8_t* p = tx_;
  p = board::ParamGet::put(p, param_id_, type, subscribe ? control::ParamGetFlags::SUBSCRIBE : 0, max_count);
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
  typedef board::ParamValue V;
  v.request_id = V::request_id(p);
  v.status = V::status(p);
  v.name_len = p[V::kName];  // the name's u8 length, its bytes after it
  v.name = reinterpret_cast<const char*>(p + V::kName + 1);
  v.type = 0;
  v.count_ = 0;
  v.elems_ = nullptr;
  v.size_ = 0;
  size_t at = V::kName + 1u + v.name_len;
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
          v.count_ = wire::get16(p + at);
          at += 2;
        }
        v.elems_ = p + at;
        const uint8_t es = detail::param_elem_size(scalar);
        for (uint16_t i = 0; good && i < v.count_; ++i) {  // every element within the payload
          size_t step = es;
          if (es == 0) step = at + 2 <= n ? 2u + wire::get16(p + at) : n + 1;
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
inline void param_element(const ParamValue& v, uint16_t i, int32_t* out) { *out = v.asInt(i); }
inline void param_element(const ParamValue& v, uint16_t i, float* out) { *out = v.asFloat(i); }
inline void param_element(const ParamValue& v, uint16_t i, bool* out) { *out = v.asBool(i); }
/** n numbers of type V from v into out (int32_t, float or bool): false unless v holds n of them. */
template <class V>
bool copy_values(void* out, const ParamValue& v, uint16_t n) {
  if (v.count() != n || (v.type & 0x7F) == kParamString) return false;
  for (uint16_t i = 0; i < n; ++i) param_element(v, i, static_cast<V*>(out) + i);
  return true;
}
/** A string from v into out (cap bytes with its terminator). */
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

#endif  // HWBRIDGE_NODE_SERVICES_PARAMS_H
