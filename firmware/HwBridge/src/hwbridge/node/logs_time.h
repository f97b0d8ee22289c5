// The bodies of NodeHandle_, part of node_impl.h: logs, time sync (2.8) and publishing.
// Included inside namespace hwbridge by node_impl.h only, which defines HWB_NODE and HWB_SELF.
#ifndef HWBRIDGE_NODE_LOGS_TIME_H
#define HWBRIDGE_NODE_LOGS_TIME_H
#ifndef HWB_NODE
#error "hwbridge/node/*.h are parts of node_impl.h: include HwBridge.h"
#endif

// ---------------------------------------------------------------------------------------------
// Logs, time, publishing

HWB_NODE bool HWB_SELF::log(uint8_t level, const char* text) {
  clock();  // the frame's send time is now, not the last spinOnce
  const size_t cap = Profile::kTxBuffer < peer_max_ ? Profile::kTxBuffer : peer_max_;
  if (state_ != kConnected || cap < 2 || !waitTx()) {  // a host max_message below 2: no log fits
    ++stats_.tx_refused;
    return false;
  }
  uint8_t* start = board::Log::put(tx_, level);
  size_t n = static_cast<size_t>(detail::put_str(start, text, cap - board::Log::kText) - start);
  while (n && (static_cast<uint8_t>(text[n]) & 0xC0) == 0x80) --n;  // cut on a UTF-8 boundary
  uint8_t* end = start + n;
  pending_ch_ = kControlChannel;
  pending_len_ = static_cast<uint16_t>(end - tx_);
  pump();
  hw_.flush();
  return true;
}

HWB_NODE void HWB_SELF::requestSyncTime() {
  if (state_ != kConnected || !(features_ & 1)) return;
  clock();  // t1 is now
  uint8_t r[board::TimeRequest::kMinSize];
  board::TimeRequest::put(r, now_);
  sendControlBe(r, sizeof r);
}

HWB_NODE void HWB_SELF::onTimeResponse(const uint8_t* p) {
  typedef board::TimeResponse T;
  const uint32_t elapsed = now_ - T::t1(p);
  if (elapsed > kMaxTimeAgeUs) return;
  const uint32_t t2s = T::t2_sec(p), t2n = T::t2_nsec(p);
  const uint32_t t3s = T::t3_sec(p), t3n = T::t3_nsec(p);
  const uint32_t busy_s = t3s - t2s;
  if (busy_s > 10 || t2n >= 1000000000UL || t3n >= 1000000000UL) return;  // nonsense: ignored
  // host busy time t3 - t2 in us
  const int32_t busy = static_cast<int32_t>(busy_s) * 1000000L +
                       (static_cast<int32_t>(t3n) - static_cast<int32_t>(t2n)) / 1000;
  int32_t rtt = static_cast<int32_t>(elapsed) - busy;
  if (rtt < 0) rtt = 0;
  // reference pair: board_ref = t4 (now), host_ref = t3 + rtt / 2
  TimeSample s;
  s.rtt_us = static_cast<uint16_t>(rtt > 65535 ? 65535 : rtt);  // above 65 ms: poor anyway
  s.board_ref = now_;
  s.host_sec = t3s;
  uint32_t half = static_cast<uint32_t>(rtt) / 2;  // µs, at most ~5 s: whole seconds first
  while (half >= 1000000UL) {
    half -= 1000000UL;
    ++s.host_sec;
  }
  s.host_nsec = t3n + half * 1000u;
  if (s.host_nsec >= 1000000000UL) {
    s.host_nsec -= 1000000000UL;
    ++s.host_sec;
  }
  const TimeSample& use = time_.add(s);  // the newest of the shortest round trips (2.8)
  host_sec_ = use.host_sec;
  host_nsec_ = use.host_nsec;
  board_ref_ = use.board_ref;
  setFlag(kTimeSynced, true);
  time_.schedule(tick_, ticks(Profile::kTimeSyncMs));
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
  clock();  // the frame's send time (and a reliable one's retransmission deadline) is now
  if (state_ != kConnected || !e.accepted_ || len > peer_max_ || !txFree() || (!kFragments && !kFixedMtu && len > mtu_)) {
    ++stats_.tx_refused;
    return false;
  }
  if (e.reliable_) {
    if (flag(kAnswerOwed)) {  // the buffer waits for a request taken back (onControl)
      ++stats_.tx_refused;
      return false;
    }
    pending_ch_ = e.channel_;
    pending_len_ = static_cast<uint16_t>(len);
    pump();
  } else {
    sendBe(e.channel_, tx_, len);
  }
  hw_.flush();
  return true;
}

#endif  // HWBRIDGE_NODE_LOGS_TIME_H
