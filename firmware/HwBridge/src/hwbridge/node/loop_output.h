// The bodies of NodeHandle_, part of node_impl.h: the loop (spinOnce, input, timers) and output
// (frames, HELLO, the table).
// Included inside namespace hwbridge by node_impl.h only, which defines HWB_NODE and HWB_SELF.
#ifndef HWBRIDGE_NODE_LOOP_OUTPUT_H
#define HWBRIDGE_NODE_LOOP_OUTPUT_H
#ifndef HWB_NODE
#error "hwbridge/node/*.h are parts of node_impl.h: include HwBridge.h"
#endif

// ---------------------------------------------------------------------------------------------
// The loop

HWB_NODE void HWB_SELF::spinOnce() {
  processInput();
  timers(false);  // processInput read the clock and pumped the reliable window just now
}

HWB_NODE void HWB_SELF::processInput() {
  if (state_ == kOff || flag(kInInput)) return;
  setFlag(kInInput, true);
  clock();
  readInput(static_cast<typename detail::Pick<detail::IsDatagramSink<Hardware>::value, detail::DatagramLink,
                                              detail::StreamLink>::type*>(nullptr));
  setFlag(kInInput, false);
  flushOut();
}

/** A byte stream: COBS runs through the decoder. */
HWB_NODE void HWB_SELF::readInput(detail::StreamLink*) {
  const size_t kBudget = 2 * FrameDecoder<Profile::kMtu, false>::kCapacity + 8;  // bytes read per call
  for (typename detail::Pick<(kBudget < 256), uint8_t, uint16_t>::type budget = kBudget; budget; --budget) {
    const int c = hw_.read();
    if (c < 0) break;
    if (dec_.push(static_cast<uint8_t>(c)) == Decoded::Frame) onFrame(dec_.frame());
  }
}

/** A datagram link (PROTOCOL.md 1.13): each datagram is one frame's body. The hardware drops
 * (and counts) datagrams that are no frame; one above the MTU is a dropped message here. */
HWB_NODE void HWB_SELF::readInput(detail::DatagramLink*) {
  for (uint8_t budget = 8; budget; --budget) {  // datagrams per call: a burst of 8, then the timers
    size_t n = 0;
    const uint8_t* body = hw_.receive(&n);
    if (body == nullptr) break;
    Frame f = {};
    if (parse_body(body, n, Profile::kMtu, &f, kAckInData) == FrameError::Ok) {
      onFrame(f);
    } else {
      ++stats_.dropped_messages;
    }
  }
}

HWB_NODE void HWB_SELF::runTimers() { timers(true); }

/** The timers; alone: not right after processInput(), so the clock is read and the reliable
 * window pumped here (spinOnce, which has just done both, saves the second time). */
HWB_NODE void HWB_SELF::timers(bool alone) {
  if (state_ == kOff || flag(kInInput)) return;
  if (alone) clock();
  if (established()) {
    if (static_cast<Tick>(tick_ - last_rx_) >= kLinkTimeout ||
        (state_ == kConfiguring && static_cast<Tick>(tick_ - timer_) >= kHandshakeTimeout)) {
      ++stats_.link_losses;
      teardown();
    } else if (alone) {
      pump();  // retransmissions (the retry limit may end the session)
    }
  }
  if (!established()) {  // the handshake, also right after a session ended: a HELLO at once
    // timer_ is the last HELLO's tick: an unsigned difference, so a long pause between runs
    // (a slow setup()) never holds the next HELLO back
    if (static_cast<Tick>(tick_ - timer_) >= hello_wait_) {
      sendHello();
      timer_ = tick_;
      hello_wait_ = hello_wait_ == 0                    ? kHelloFirst
                    : hello_wait_ < kHelloInterval / 2 ? static_cast<uint8_t>(hello_wait_ * 2)
                                                       : kHelloInterval;
    }
    hw_.flush();
    return;
  }
  if (state_ == kConnected) {
    // set by serviceClient and requestParam, which check their own deadlines
    if (on_response_) on_response_(this, nullptr, kCallTimeout);
    if (on_param_) on_param_(this, nullptr, kParamTimeout);
    if (Profile::kTimeSyncMs && (features_ & 1) && time_.due(tick_)) {
      requestSyncTime();
      time_.schedule(tick_, kTimeRetry);
    }
  }
  if (static_cast<Tick>(tick_ - last_tx_) >= kHeartbeat) {
    ++stats_.heartbeats_sent;
    uint8_t hb[board::Heartbeat::kMinSize];
    board::Heartbeat::put(hb);
    sendControlBe(hb, sizeof hb);
  }
  hw_.flush();
}

HWB_NODE void HWB_SELF::spinFor() {
  setFlag(kInInput, false);
  processInput();
  timers(false);
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
  const bool lead = markTx();
  // ACK_IN_DATA (PROTOCOL.md 2.4): a due ACK without a bitmap rides in this frame, when its
  // payload leaves the ACK byte room in the MTU
  if (kAckInData && (features_ & control::Features::ACK_IN_DATA) && rel_rx_.ack_needed() &&
      rel_rx_.held() == 0 && f.size < mtu_) {
    uint8_t bitmap[kMaxSackBytes];
    size_t bitmap_len;
    const uint8_t ack = rel_rx_.make_ack(bitmap, &bitmap_len);
    write_frame(hw_, h, f.payload, f.size, &ack, 1, static_cast<uint8_t>(lead | kCarryAck));
    return;
  }
  write_frame(hw_, h, f.payload, f.size, nullptr, 0, lead);
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
  uint8_t h[board::Hello::kMinSize];
  board::Hello::put(h, control::Role::DEVICE, established() ? control::HelloFlags::ESTABLISHED : 0, id_, peer_,
                    Profile::kMtu, Profile::kMaxMessage, Profile::kWindow, isn_, kOwnFeatures);
  setFlag(kLead, true);  // 1.3: a HELLO is always led by 0x00
  sendControlBe(h, sizeof h);
}

/** After input: the ACK that is due (every one at once: this board never holds ACKs back),
 * then what the reliable window lets out. With ACK_IN_DATA the ACK rides in the first frame
 * the window lets out (emit), and goes alone after them when none did. */
HWB_NODE void HWB_SELF::flushOut() {
  if (!kAckInData || !(features_ & control::Features::ACK_IN_DATA)) {
    if (established() && rel_rx_.ack_needed()) rel_rx_.write_ack(hw_, markTx());
  }
  pump();
  if (kAckInData && established() && rel_rx_.ack_needed()) rel_rx_.write_ack(hw_, markTx());
  hw_.flush();
}

/** Moves the waiting message (or the next table message) into the reliable window and sends
 * every frame that is due. */
HWB_NODE void HWB_SELF::pump() {
  if (!established()) return;
  while (!rel_tx_.sending() && rel_tx_.free_slots()) {
    if (pending_len_ == 0 && (state_ != kConfiguring || !queueTable())) break;
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

/** Builds the next message of the topic table (2.6) in tx_; false when the table is done.
 * Called by pump() in state kConfiguring only. */
HWB_NODE bool HWB_SELF::queueTable() {
  if (table_pos_ > entry_count_ + 1) return false;
  uint8_t* p = tx_;
  const size_t cap = Profile::kTxBuffer;
  static_assert(Profile::kTxBuffer >= 24, "kTxBuffer must hold at least 24 bytes");
  if (table_pos_ == 0) {  // BOARD_INFO
    p = board::BoardInfo::put(p, entry_count_);
    uint8_t* len = p++;
    p = detail::put_str(p, name_, cap - 5 < 255 ? cap - 5 : 255);
    *len = static_cast<uint8_t>(p - len - 1);
    const size_t room = cap - static_cast<size_t>(p - tx_) - 1;
    const uint8_t ul = uid_len_ <= room ? uid_len_ : static_cast<uint8_t>(room);
    *p++ = ul;
    if (ul) memcpy(p, uid_, ul);  // uid_ may be null when ul is 0
    p += ul;
    p = detail::put_str(p, firmware_, cap - static_cast<size_t>(p - tx_));
    p = detail::put_str_P(p, detail::Identity<>::text, cap - static_cast<size_t>(p - tx_));
  } else if (table_pos_ <= entry_count_) {  // TOPIC
    Entry* e = entries_;
    for (uint8_t i = 1; i < table_pos_; ++i) e = e->next_;
    p = board::Topic::put(p, e->channel_, e->kind_, e->reliable_ ? control::EntryFlags::RELIABLE : 0);
    flash_copy(p, e->hook_(e, Entry::kOpMd5, nullptr, nullptr, nullptr), 16);
    p += 16;
    uint8_t* len = p++;
    p = detail::put_str(p, e->name_, cap - 21);
    *len = static_cast<uint8_t>(p - len - 1);
    p = detail::put_str_P(p, e->hook_(e, Entry::kOpType, nullptr, nullptr, nullptr),
                          cap - static_cast<size_t>(p - tx_));
  } else {  // TABLE_END
    p = board::TableEnd::put(p, entry_count_);
  }
  ++table_pos_;
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(p - tx_);
  return true;
}

#endif  // HWBRIDGE_NODE_LOOP_OUTPUT_H
