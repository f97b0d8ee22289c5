// The user API of the board side: a rosserial-like NodeHandle with publishers, subscribers,
// service servers and clients, parameters, logs and host time, over the native session
// (PROTOCOL.md Part 2). No heap: every object is a static the sketch declares; sizes are the
// template parameters of a Profile.
//
//   #include <HwBridge.h>
//   #include <std_msgs/String.h>
//   hwbridge::NodeHandle nh;                    // HelloWorldProfile + Arduino Serial
//   std_msgs::String msg;
//   hwbridge::Publisher<std_msgs::String> chatter("chatter");
//   void setup() { nh.initNode(115200, "uno"); nh.advertise(chatter); }
//   void loop() { msg.data.assign("hello"); chatter.publish(msg); nh.spinOnce(); delay(100); }
//
// Every registration (advertise, subscribe, advertiseService, serviceClient) must happen before
// the first spinOnce(): the table is announced to the host once per session, in that order,
// and channels are numbered 1, 2, ... in registration order.
#ifndef HWBRIDGE_NODE_H
#define HWBRIDGE_NODE_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "config.h"
#include "decoder.h"
#include "encoder.h"
#include "fragment.h"
#include "frame.h"
#include "streams.h"
#include "timesync.h"
#include "progmem.h"
#include "../hwbridge_msg.h"
#include "../hwbridge_control.h"
#include "identity.h"

namespace hwbridge {

// ---------------------------------------------------------------------------------------------
// Profiles: the sizes and features of a node, chosen at compile time.

/**
 * The smallest node (PROTOCOL.md 2.13 "hello world"): MTU 64, max_message 64, window 1, no
 * reassembly buffer (a host never sends it a message above one frame), messages of up to 64
 * bytes sent, no own time requests (it still answers the host's), no host logs.
 */
struct HelloWorldProfile {
  static const uint16_t kMtu = 64;           ///< largest frame payload accepted (>= 24)
  static const uint16_t kMaxMessage = 64;    ///< largest message received (reassembly above kMtu)
  static const uint8_t kWindow = 1;          ///< reliable frames in flight (1..64)
  static const uint16_t kTxBuffer = 64;      ///< largest message sent (serialization buffer)
  /// TIME_SYNC | PARAM_PUSH (| 4 = HOST_LOG) | 16 = SERVICE_CHANNELS | 32 = SHORT_CALLS; | 8 =
  /// ACK_IN_DATA with HWBRIDGE_ACK_IN_DATA defined
  static const uint8_t kFeatures = 51 | (HWBRIDGE_ACK_IN_DATA ? 8 : 0);
  static const uint16_t kTimeSyncMs = 0;     ///< own time requests every this many ms (0: none)
  static const uint16_t kParamTimeoutMs = 2000;
  static const uint16_t kServiceTimeoutMs = 5000;
  static const bool kFixedRto = true;  ///< 100 ms doubling per retry, no RTT estimate (2.4 allows it)
};

/** PROTOCOL.md 2.13 "comfortable": max_message 192 with reassembly, window 2, messages of up to
 * 192 bytes sent, time sync every 5 s, host logs accepted. */
struct ComfortableProfile {
  static const uint16_t kMtu = 64;
  static const uint16_t kMaxMessage = 192;
  static const uint8_t kWindow = 2;
  static const uint16_t kTxBuffer = 192;
  static const uint8_t kFeatures = 55 | (HWBRIDGE_ACK_IN_DATA ? 8 : 0);
  static const uint16_t kTimeSyncMs = 5000;
  static const uint16_t kParamTimeoutMs = 2000;
  static const uint16_t kServiceTimeoutMs = 5000;
  static const bool kFixedRto = false;  ///< RTO after RFC 6298, fast retransmit
};

// ---------------------------------------------------------------------------------------------
// Values shared with the protocol

/** Log levels (PROTOCOL.md 2.8), as rosserial numbers them. */
enum LogLevel : uint8_t { kDebug = 0, kInfo = 1, kWarn = 2, kError = 3, kFatal = 4 };

/** Parameter types of PARAM_GET / PARAM_VALUE; `| kParamList` makes a list. */
enum ParamType : uint8_t {
  kParamAny = 0,
  kParamBool = 1,
  kParamInt32 = 2,
  kParamFloat32 = 3,
  kParamString = 4,
  kParamList = 0x80,
};

/** Status of a parameter answer: the host's (OK .. TOO_LARGE) or the board's own. */
enum ParamStatus : uint8_t {
  kParamOk = 0,
  kParamNotFound = 1,
  kParamTypeMismatch = 2,
  kParamTooLarge = 3,
  kParamTimeout = 0x10,       ///< no answer within the profile's kParamTimeoutMs
  kParamSessionReset = 0x11,  ///< the session ended before the answer
  kParamNotConnected = 0x12,  ///< refused: no session, or another request is pending
};

/** Status of a service call made by the board. */
enum CallStatus : uint8_t {
  kCallOk = 0,
  kCallError = 1,        ///< the host's service failed
  kCallNoService = 2,    ///< the host serves nothing on that channel
  kCallTimeout = 0x10,
  kCallSessionReset = 0x11,
  kCallNotConnected = 0x12,  ///< refused: not connected, another call pending, or too large
  kCallBadResponse = 0x13,   ///< the response does not deserialize into the Response type
};

/**
 * One parameter answer. Its elements point into the node's receive buffer: read them inside the
 * callback. For a list, count() elements; a scalar is a list of one.
 */
class ParamValue {
 public:
  uint16_t request_id;  ///< 0 for a value the host pushed (a subscribed parameter changed)
  uint8_t status;       ///< ParamStatus
  uint8_t type;         ///< ParamType of the value (kParamList bit for lists), when status is kParamOk
  const char* name;     ///< not NUL-terminated: name_len bytes (empty for board-side errors)
  uint8_t name_len;

  bool ok() const { return status == kParamOk; }
  uint16_t count() const { return count_; }
  /** Element i as int32 (bools as 0/1; floats truncated); 0 when out of range. */
  int32_t asInt(uint16_t i = 0) const;
  float asFloat(uint16_t i = 0) const;
  bool asBool(uint16_t i = 0) const { return asInt(i) != 0; }
  /** Copies string element i (NUL-terminated, cut to cap - 1 bytes); its full length. */
  size_t asString(char* out, size_t cap, uint16_t i = 0) const;
  /** True when the name equals s. */
  bool is(const char* s) const { return strlen(s) == name_len && memcmp(s, name, name_len) == 0; }

  // internal
  const uint8_t* elems_;
  size_t size_;
  uint16_t count_;
};

typedef void (*ParamCallback)(const ParamValue& value);
typedef void (*LogCallback)(uint8_t level, const char* text, size_t len);

/** Counters of a node (cumulative over sessions; `Counter`: 8-bit on AVR, 16-bit elsewhere,
 * wrapping). The traffic ones (`TrafficCounter`: sessions, HELLOs, heartbeats) read 0 on AVR
 * unless HWBRIDGE_TRAFFIC_COUNTERS is 1 (config.h). */
struct NodeStats {
  TrafficCounter sessions;  ///< sessions established
  Counter link_losses;       ///< ended by the link timeout or the retry limit
  Counter peer_resets;       ///< ended by a host restart, GOODBYE or a dropped session
  Counter protocol_errors;   ///< malformed or unexpected control messages, refused entries
  Counter mismatches;        ///< TOPIC_ACK MISMATCH (the host expects another type or md5)
  Counter refused_entries;   ///< TOPIC_ACK INVALID
  Counter dropped_messages;  ///< data on unknown, refused, wrong-direction channels, or too large
  Counter tx_refused;        ///< sends refused (not connected, window full, too large), and service
                             ///< requests that could not be answered (PROTOCOL.md 2.8)
  Counter ignored_frames;    ///< frames outside a session
  TrafficCounter hellos_sent;
  TrafficCounter heartbeats_sent;
#if !defined(__AVR__)
  /// times this end had not run for longer than 200 ms (PROTOCOL.md 2.9: only the first 200 ms
  /// of such a gap count towards the link timeout); counted by a Hardware that shares the CPU
  /// (host builds: detail::SharesCpu), always 0 on bare metal
  Counter stalls;
#endif
};

class NodeBase;

namespace detail {
/** Tags of the two kinds of link the node reads (detail::IsDatagramSink tells them apart). */
struct StreamLink {};
struct DatagramLink {};
/** Tags of a Hardware that runs alone (bare metal) or shares the CPU (detail::SharesCpu). */
struct OwnCpu {};
struct SharedCpu {};
}  // namespace detail

/** Where a service server's response goes (the node's transmit buffer). */
struct ServiceOut {
  uint8_t* buf;
  size_t cap;
};

// ---------------------------------------------------------------------------------------------
// Entries of the topic table

/** Entry kinds (PROTOCOL.md 2.6). */
enum EntryKind : uint8_t { kPublisher = 0, kSubscriber = 1, kServiceServer = 2, kServiceClient = 3 };

/**
 * One row of the topic table: the base of Publisher, Subscriber, ServiceServer, ServiceClient.
 * Constant-initialized (no static constructor); linked into its node by registration.
 */
class Entry {
 public:
  /** What the node asks of the typed part (hooks, one function per entry type). */
  enum Op : uint8_t { kOpType = 0, kOpMd5 = 1, kOpDeliver = 2 };
  /** kOpType/kOpMd5: returns the type name / the md5's 16 bytes (in flash on AVR). kOpDeliver: handles a
   * message of *len bytes at data (a subscriber's callback; a server's callback, writing the
   * response's length to *len; a client's response deserialized into obj); returns nullptr on
   * success, non-null when the bytes do not deserialize. */
  typedef const char* (*Hook)(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj);

  constexpr Entry(const char* name, uint8_t kind, bool reliable, Hook hook)
      : name_(name), hook_(hook), next_(nullptr), node_(nullptr), channel_(0), kind_(kind),
        reliable_(reliable), accepted_(false) {}

  uint8_t channel() const { return channel_; }
  /** The host accepted this entry in the current session (it can be used). */
  bool accepted() const { return accepted_; }
  const char* name() const { return name_; }

  // internal (used by the node)
  const char* name_;
  Hook hook_;
  Entry* next_;
  NodeBase* node_;
  uint8_t channel_;
  uint8_t kind_;
  bool reliable_;
  bool accepted_;
};

// ---------------------------------------------------------------------------------------------
// The node: hardware-independent part (what entries call)

/**
 * What Publisher, ServiceClient and friends call; NodeHandle_ is the real class. Not used
 * directly by sketches.
 */
class NodeBase {
 public:
  /** The serialization buffer for one outgoing message, or nullptr when it is busy (a previous
   * message still being sent) and cannot be freed now. */
  uint8_t* txBuffer(size_t* cap) { return tx_fn_(this, cap); }
  /** Sends len bytes of txBuffer() on entry e's channel (best effort or reliable). */
  bool sendEntry(Entry& e, size_t len) { return send_fn_(this, e, len); }
  /** Sends a SERVICE_REQUEST whose body (len bytes) is already at txBuffer() + 4 and spins
   * until its answer; an OK response body is deserialized into res by e's hook. */
  uint8_t callService(Entry& e, size_t len, uint16_t timeout_ms, void* res) {
    return call_fn_(this, e, len, timeout_ms, res);
  }

 protected:
  // Set by the registrations that need them (advertise, serviceClient): a sketch without a
  // service client links no client code. Function pointers instead of virtual functions: no
  // vtable in RAM, and nothing kept that is never called.
  uint8_t* (*tx_fn_)(NodeBase*, size_t*) = nullptr;
  bool (*send_fn_)(NodeBase*, Entry&, size_t) = nullptr;
  uint8_t (*call_fn_)(NodeBase*, Entry&, size_t, uint16_t, void*) = nullptr;
};

// ---------------------------------------------------------------------------------------------
// Typed entries

/** Publishes messages of type T (a generated message header) on a topic. */
template <class T>
class Publisher : public Entry {
 public:
  /** name: the topic ("chatter" or "/chatter"), kept as a pointer (use a string literal).
   * reliable: send on the reliable stream (acknowledged, resent) instead of best effort. */
  constexpr explicit Publisher(const char* name, bool reliable = false)
      : Entry(name, kPublisher, reliable, &hook) {}
  /** Serializes and sends msg; false when not connected, refused by the host, too large for
   * the node's kTxBuffer, or (reliable) the window stays full. */
  bool publish(const T& msg);

 private:
  static const char* hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj);
};

/** Receives messages of type T on a topic; the callback runs inside spinOnce(). */
template <class T>
class Subscriber : public Entry {
 public:
  typedef void (*Callback)(const T& msg);
  constexpr Subscriber(const char* name, Callback cb, bool reliable = false)
      : Entry(name, kSubscriber, reliable, &hook), cb_(cb) {}

 private:
  Callback cb_;
  static const char* hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj);
};

/** Serves a service of type Srv (Srv::Request, Srv::Response) to the host; the callback runs
 * inside spinOnce() and fills the response. */
template <class Srv>
class ServiceServer : public Entry {
 public:
  typedef typename Srv::Request Request;
  typedef typename Srv::Response Response;
  typedef void (*Callback)(const Request& req, Response& res);
  constexpr ServiceServer(const char* name, Callback cb)
      : Entry(name, kServiceServer, true, &hook), cb_(cb) {}

 private:
  Callback cb_;
  static const char* hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj);
};

/** Calls a host service of type Srv. */
template <class Srv>
class ServiceClient : public Entry {
 public:
  typedef typename Srv::Request Request;
  typedef typename Srv::Response Response;
  constexpr explicit ServiceClient(const char* name)
      : Entry(name, kServiceClient, true, &hook) {}
  /**
   * Sends req and spins the node until the response (returns kCallOk and fills res), an error
   * (kCallError, kCallNoService), timeout_ms (0: the profile's kServiceTimeoutMs), the end of
   * the session, or a refusal (kCallNotConnected). Call it from loop(), not from a callback.
   */
  uint8_t call(const Request& req, Response& res, uint16_t timeout_ms = 0);

 private:
  static const char* hook(Entry* self, uint8_t op, const uint8_t* data, size_t* len, void* obj);
};

// ---------------------------------------------------------------------------------------------
// The node

/**
 * A board's node: the native session over Hardware, sized by Profile.
 *
 * Hardware concept: init(baud) (bool), int read() (a byte or -1), put(uint8_t) and flush()
 * (bytes out), uint32_t micros() (wrapping), uint32_t seed() (entropy for the session id).
 * A datagram Hardware (`static const bool kDatagram = true`, hardware_udp.h) has instead of
 * read() `const uint8_t* receive(size_t* n)` (the next datagram, or nullptr) and, after the
 * put() of each frame's body, endDatagram() (PROTOCOL.md 1.13: no COBS, one frame a datagram).
 */
template <class Hardware, class Profile = HelloWorldProfile>
class NodeHandle_ : public NodeBase {
 public:
  /** Opens the hardware at baud and starts announcing the board (its first HELLO goes out at
   * the first spinOnce). name is the board's name shown by the host; firmware its version. */
  void initNode(uint32_t baud = 115200, const char* name = "arduino", const char* firmware = "");
  /** As initNode, with the hardware already opened by the caller (tests, custom links). */
  void begin(const char* name = "arduino", const char* firmware = "");

  /** Registers entries (before the first spinOnce). False when 255 entries exist already or
   * the entry is registered elsewhere. */
  template <class T> bool advertise(Publisher<T>& p) {
    tx_fn_ = &txThunk;
    send_fn_ = &sendThunk;
    return add(p);
  }
  template <class T> bool subscribe(Subscriber<T>& s) {
    if (on_data_ == nullptr) on_data_ = &dataThunk;  // channelThunk, once a service is there, delivers to it too
    return add(s);
  }
  template <class S> bool advertiseService(ServiceServer<S>& s) {
    on_request_ = &requestThunk;
    on_data_ = &channelThunk;  // calls on the service's channel (SERVICE_CHANNELS)
    detail::EagerWrites<>::on = true;  // answers start sooner
#if defined(__AVR__)
    detail::use_early_writer<Hardware>();
#endif
    return add(s);
  }
  template <class S> bool serviceClient(ServiceClient<S>& c) {
    tx_fn_ = &txThunk;
    call_fn_ = &callThunk;
    on_response_ = &responseThunk;
    on_data_ = &channelThunk;
    return add(c);
  }

  /** Reads what the hardware has, handles it, runs the timers, writes what is due. Call it
   * often (every loop(); at least every few ms while messages flow). */
  void spinOnce();
  /** The two halves of spinOnce (tests replay transcripts with them). */
  void processInput();
  void runTimers();

  /** CONNECTED: READY received, topics usable. */
  bool connected() const { return state_ == kConnected; }
  /** Connected and a publish() now would not wait: no reliable message waits for a window
   * slot (a full window makes the next publish, log or call spin the node for up to 250 ms). A
   * sketch that must never block asks before it publishes. */
  bool txReady() const { return state_ == kConnected && txFree(); }

  /** Host time now (ROS time; zeros before the first time sync answer). */
  void now(uint32_t* sec, uint32_t* nsec);
  /** True once a time sync answer arrived in this session. */
  bool timeSynced() const { return flag(kTimeSynced); }
  /** How many answers to its own time requests the node keeps now (at most 4; 0 without
   * kTimeSyncMs): now() follows the newest of those with the shortest round trips. */
  uint8_t timeSamples() const { return time_.count(); }
  /** Asks the host for its time now (a profile with kTimeSyncMs > 0 also does it periodically;
   * with kTimeSyncMs 0 the board reads no answers and host time comes from the host's own
   * time requests). */
  void requestSyncTime();

  /** Logs to the host (reliable; cut to fit). False when not connected or the window stays
   * full. Each spins the node until the line is queued. */
  bool log(uint8_t level, const char* text);
  bool logDebug(const char* t) { return log(kDebug, t); }
  bool logInfo(const char* t) { return log(kInfo, t); }
  bool logWarn(const char* t) { return log(kWarn, t); }
  bool logError(const char* t) { return log(kError, t); }
  bool logFatal(const char* t) { return log(kFatal, t); }
  // rosserial's names
  bool logdebug(const char* t) { return log(kDebug, t); }
  bool loginfo(const char* t) { return log(kInfo, t); }
  bool logwarn(const char* t) { return log(kWarn, t); }
  bool logerror(const char* t) { return log(kError, t); }
  bool logfatal(const char* t) { return log(kFatal, t); }
  /** Logs the host sends (only when kFeatures has HOST_LOG, 4). */
  void onLog(LogCallback cb) { log_cb_ = cb; }

  /**
   * Parameters, non-blocking: asks the host for name as type (ParamType; kParamAny: its own
   * type). Exactly one call of cb follows (the answer, kParamTimeout, kParamSessionReset or
   * kParamNotConnected), inside spinOnce(). With subscribe, later changes pushed by the host
   * also go to cb (request_id 0; the last subscribing callback gets all pushes). max_count
   * caps list lengths (0: none). Returns the request id (0 when refused: cb already ran).
   * One request is pending at a time.
   */
  uint16_t requestParam(const char* name, uint8_t type, ParamCallback cb, bool subscribe = false,
                        uint16_t max_count = 0);
  /**
   * Parameters, blocking (as rosserial): spins until the answer; fills length values and
   * returns true when the host has name with exactly length elements of a convertible type.
   */
  bool getParam(const char* name, int32_t* value, uint16_t length = 1, uint16_t timeout_ms = 0);
  bool getParam(const char* name, float* value, uint16_t length = 1, uint16_t timeout_ms = 0);
  bool getParam(const char* name, bool* value, uint16_t length = 1, uint16_t timeout_ms = 0);
  /** A string parameter into out (NUL-terminated, at most cap - 1 bytes). */
  bool getParamString(const char* name, char* out, size_t cap, uint16_t timeout_ms = 0);

  /** Counters. */
  const NodeStats& stats() const { return stats_; }
  Hardware& getHardware() { return hw_; }
  uint32_t sessionId() const { return id_; }
  /** The unique id sent in BOARD_INFO (kept as a pointer; at most 255 bytes). */
  void setUniqueId(const uint8_t* id, uint8_t len) { uid_ = id; uid_len_ = len; }
  /** Fixes the session id and ISN instead of random ones (tests; before begin/initNode). */
  void setIdentity(uint32_t session_id, uint8_t isn) { id_ = session_id; fixed_isn_ = isn; setFlag(kFixed, true); }

  // what entries call through NodeBase
  uint8_t* takeTxBuffer(size_t* cap);
  bool sendOn(Entry& e, size_t len);
  uint8_t call(Entry& e, size_t len, uint16_t timeout_ms, void* res);


 private:
  enum State : uint8_t { kOff = 0, kHandshake, kConfiguring, kConnected };
  static const uint16_t kMinMtu = 24;
  // On a service's own channel (SERVICE_CHANNELS, 2.8) a request is its id, then the body; an
  // answer its id and status, then the body: SERVICE_REQUEST and SERVICE_RESPONSE without their
  // opcode and channel (kToCall bytes).
  static const uint8_t kCallHead = 2;
  static const uint8_t kAnswerHead = 3;
  static const uint8_t kToCall = control::board::ServiceRequest::kBody - kCallHead;
  // With SHORT_CALLS too (2.8) the head is one byte: the request id (1..127), and in a response
  // bit 7 set when a status byte follows (any status but OK).
  static const uint8_t kShortIdMask = 0x7F;
  static const uint8_t kStatusFollows = 0x80;
  static const uint32_t kMaxTimeAgeUs = 10000000UL;
  // The session's timers count 16-bit ticks of 1.024 ms, the microsecond clock shifted right by
  // 10 (no division on the board): deadlines up to 33 s ahead. Intervals are the protocol's
  // milliseconds in ticks, rounded (PROTOCOL.md 2.11).
  typedef uint16_t Tick;
  static constexpr Tick ticks(uint32_t ms) { return static_cast<Tick>((ms * 125 + 64) / 128); }
  static const uint8_t kHelloFirst = ticks(50);     // the first HELLO retry; doubling up to
  static const uint8_t kHelloInterval = ticks(250);  // ... hello_interval
  static const Tick kHeartbeat = ticks(100);
  static const Tick kIdle = ticks(100);  // a leading 0x00 after this long without sending (1.3)
  static const Tick kLinkTimeout = ticks(800);
  static const Tick kHandshakeTimeout = ticks(3000);
  static const Tick kTimeRetry = ticks(1000);
  static const uint16_t kMaxTimeoutMs = 30000;
  // 16-bit ticks compare within 32.7 s: the profile's timeouts must stay below that
  static_assert(Profile::kParamTimeoutMs <= kMaxTimeoutMs, "kParamTimeoutMs: at most 30000 ms");
  static_assert(Profile::kServiceTimeoutMs <= kMaxTimeoutMs, "kServiceTimeoutMs: at most 30000 ms");
  static_assert(Profile::kTimeSyncMs <= kMaxTimeoutMs, "kTimeSyncMs: at most 30000 ms");
  static bool reached(Tick now, Tick at) { return static_cast<int16_t>(now - at) >= 0; }
  /** A timeout in ms as ticks (ms * 125 / 128 by shifts), at most kMaxTimeoutMs. */
  static Tick msTicks(uint16_t ms) {
    if (ms > kMaxTimeoutMs) ms = kMaxTimeoutMs;
    return static_cast<Tick>(ms - (ms >> 6) - (ms >> 7));
  }
  static const uint16_t kReassembly = Profile::kMaxMessage > Profile::kMtu ? Profile::kMaxMessage : 0;

  bool add(Entry& e);
  void readInput(detail::StreamLink*);
  void readInput(detail::DatagramLink*);
  bool established() const { return state_ >= kConfiguring; }
  __attribute__((noinline)) void onFrame(const Frame& f);
  void onBestEffort(const Frame& f);
  __attribute__((noinline)) void deliver(const Frame& f);
  void onMessage(const Message& m, bool reliable);
  void onControl(const uint8_t* p, size_t n, bool reliable);
  void onHello(const uint8_t* p);
  void onData(const Message& m);
  void onTopicAck(const uint8_t* p, size_t n);
  void onChannel(const Message& m);
  bool admitRequest();
  void onServiceRequest(uint8_t channel, uint16_t id, const uint8_t* body, size_t n);
  void onServiceResponse(uint16_t id, uint8_t status, const uint8_t* body, size_t n);
  void onParamValue(const uint8_t* p, size_t n);
  void onTimeResponse(const uint8_t* p);
  __attribute__((noinline)) void establish(const uint8_t* hello);
  void teardown();
  void protocolError() { ++stats_.protocol_errors; }
  void sendHello();
  void sendControlBe(const uint8_t* p, size_t n) { sendBe(kControlChannel, p, n); }
  void sendBe(uint8_t channel, const uint8_t* p, size_t n);
  void emit(const Frame& f);
  void clock();
  void stalled(Tick, detail::OwnCpu*) {}
  void stalled(Tick before, detail::SharedCpu*);
  void timers(bool alone);
  __attribute__((noinline)) bool markTx();
  void flushOut();
  void pump();
  // Not inlined into pump(): its string copies keep a dozen addresses into tx_ live, which
  // pump() would otherwise compute and save on every call (94 B of flash on the Uno, and some
  // 30 cycles an idle spinOnce); pump() calls it only while configuring.
  __attribute__((noinline)) bool queueTable();
  bool txFree() const { return pending_len_ == 0 && !rel_tx_.sending(); }
  bool waitTx();
  void spinFor();
  Entry* entryAt(uint8_t channel);  // the entry on channel, accepted or not; nullptr if none
  Entry* entryOn(uint8_t channel, uint8_t kind);  // the accepted entry of that kind on channel
  uint16_t newRequestId();
  void finishParam(uint8_t status, const ParamValue* v);
  bool blockingParam(const char* name, uint8_t type, void* out, uint16_t length, uint16_t timeout_ms,
                     bool (*copy)(void*, const ParamValue&, uint16_t));
  static uint8_t* txThunk(NodeBase* n, size_t* cap) { return static_cast<NodeHandle_*>(n)->takeTxBuffer(cap); }
  static bool sendThunk(NodeBase* n, Entry& e, size_t len) { return static_cast<NodeHandle_*>(n)->sendOn(e, len); }
  static uint8_t callThunk(NodeBase* n, Entry& e, size_t len, uint16_t t, void* res) {
    return static_cast<NodeHandle_*>(n)->call(e, len, t, res);
  }
  // Handlers of what only some sketches need, set by the calls that need them (a sketch
  // without a service, client or parameter request links none of their code).
  typedef void (*Handler)(NodeHandle_*, const uint8_t*, size_t);
  static void dataThunk(NodeHandle_* n, const Message& m) { n->onData(m); }
  // with a service server or client: a message on a service's channel is a call (2.8)
  static void channelThunk(NodeHandle_* n, const Message& m) { n->onChannel(m); }
  // SERVICE_REQUEST (a control message): its channel, request id and body
  static void requestThunk(NodeHandle_* n, const uint8_t* p, size_t len) {
    n->onServiceRequest(control::board::ServiceRequest::channel(p), control::board::ServiceRequest::request_id(p),
                        p + control::board::ServiceRequest::kBody, len - control::board::ServiceRequest::kBody);
  }
  // A response: a SERVICE_RESPONSE (a control message, len bytes), or with kOwnChannel added
  // to len the request id, status and body on the pending call's own channel (onChannel), or
  // with kShortHead added too the one-byte head of SHORT_CALLS (2.8: the id, bit 7 set when the
  // status follows it). onChannel checked the lengths and the status.
  // p nullptr: the pending call, if any, ends with the status len (a session reset; a timeout
  // once its deadline passed)
  static const size_t kOwnChannel = static_cast<size_t>(1) << (sizeof(size_t) * 8 - 1);
  static const size_t kShortHead = kOwnChannel >> 1;
  static void responseThunk(NodeHandle_* n, const uint8_t* p, size_t len) {
    if (p != nullptr) {
      if (len & kShortHead) {
        len &= ~(kOwnChannel | kShortHead);
        const uint8_t head = *p++;
        uint8_t status = control::ServiceStatus::OK;
        --len;
        if (head & kStatusFollows) {
          status = *p++;
          --len;
        }
        n->onServiceResponse(head & kShortIdMask, status, p, len);
        return;
      }
      if (len & kOwnChannel) {
        len &= ~kOwnChannel;
      } else if (n->call_entry_ == nullptr ||
                 control::board::ServiceResponse::channel(p) != n->call_entry_->channel_) {
        return;  // not ours
      } else {
        p += kToCall;
        len -= kToCall;
      }
      n->onServiceResponse(wire::get16(p), p[kAnswerHead - 1], p + kAnswerHead, len - kAnswerHead);
    } else if (n->call_state_ == 1 && (len != kCallTimeout || reached(n->tick_, n->timer_))) {
      n->call_status_ = static_cast<uint8_t>(len);
      n->call_state_ = 2;
    }
  }
  // p nullptr: the pending request, if any, ends with the status len (a session reset; a
  // timeout once its deadline passed)
  static void paramThunk(NodeHandle_* n, const uint8_t* p, size_t len) {
    if (p != nullptr) {
      n->onParamValue(p, len);
    } else if (n->param_id_ && (len != kParamTimeout || reached(n->tick_, n->param_deadline_))) {
      n->finishParam(static_cast<uint8_t>(len), nullptr);
    }
  }

  // A board whose largest message fits its own MTU never fragments: with window 1 and the fixed
  // RTO, its reliable sender is one slot (SingleFrameSender).
  static const bool kFragments = Profile::kTxBuffer > Profile::kMtu;
  /** The profile announces ACK_IN_DATA (PROTOCOL.md 2.4): without it none of its code is built. */
  static const bool kAckInData =
      (Profile::kFeatures & control::Features::ACK_IN_DATA) != 0 && !detail::NoAckInData<Hardware>::value;
  /** The features this node announces: the profile's, without ACK_IN_DATA where it is left out. */
  static const uint8_t kOwnFeatures =
      kAckInData ? Profile::kFeatures
                 : static_cast<uint8_t>(Profile::kFeatures & ~control::Features::ACK_IN_DATA);
  // ... and if that message fills its MTU, every session's MTU is its own
  static const bool kFixedMtu = Profile::kTxBuffer == Profile::kMtu;
  typedef typename detail::Pick<!kFragments && Profile::kWindow == 1 && Profile::kFixedRto,
                                SingleFrameSender<Profile::kMtu>,
                                ReliableSender<Profile::kWindow, Profile::kMtu, Profile::kFixedRto> >::type RelTx;

  // Every member has an initializer, so that the implicit constructor is constexpr: a global
  // node is initialized at compile time (no static constructor on the board). The members used
  // most come first: on AVR a member within 63 bytes of the object's start is one instruction
  // away (ldd/std), one further needs the address computed first.
  uint8_t state_ = 0;
  uint8_t flags_ = 0;  // kFixed | kInInput | kTimeSynced | kLead | kAnswerOwed
  Tick tick_ = 0;  // now_ >> 10
  // timer_, by state: the last HELLO (handshake), the start of the table (configuring), the
  // pending service call's deadline (connected)
  Tick timer_ = 0, last_rx_ = 0, last_tx_ = 0;
  uint16_t mtu_ = 0;
  uint16_t peer_max_ = 0;  // the host's max_message (65535 for anything above)
  uint16_t pending_len_ = 0;  // a reliable message in tx_ waiting for a free slot
  uint8_t pending_ch_ = 0;
  uint8_t features_ = 0;
  uint8_t isn_ = 0, fixed_isn_ = 0;
  uint8_t entry_count_ = 0;
  uint8_t table_pos_ = 0;
  uint8_t hello_wait_ = 0;  // ticks from the last HELLO to the next: 0, 50, 100, 200, 250 ms
  uint8_t call_state_ = 0;   // 0 none, 1 waiting, 2 answered
  uint8_t call_status_ = 0;
  uint8_t sync_state_ = 0;   // 0 none, 1 waiting, 2 answered ok, 3 failed
  uint8_t uid_len_ = 0;
  Entry* entries_ = nullptr;
  NodeStats stats_{};
  RelTx rel_tx_{};
  uint32_t now_ = 0;   // microseconds, at the last clock()
  Hardware hw_{};
  BestEffortSender be_tx_{};
  BestEffortReceiver be_rx_{};
  // A window above 1 holds early frames (window - 1 of them): a receiver that drops them makes
  // the host's per-frame backoff grow for every frame after a gap (PROTOCOL.md 2.4).
  // Window 1 holds nothing: the one-frame receiver.
  typename detail::Pick<Profile::kWindow == 1, SingleFrameReceiver<Profile::kMtu>,
                        ReliableReceiver<Profile::kWindow, Profile::kMtu, Profile::kWindow - 1> >::type rel_rx_{};
  uint32_t id_ = 0, peer_ = 0, be_peer_ = 0;
  // own time requests only with kTimeSyncMs (a byte otherwise)
  TimeSync<Profile::kTimeSyncMs != 0 ? 4 : 0> time_{};  // own requests: the next, the samples
  Tick param_deadline_ = 0;
  uint16_t next_request_ = 0;
  uint16_t param_id_ = 0, call_id_ = 0;
  uint16_t sync_len_ = 0;
  const char* name_ = nullptr;
  const char* firmware_ = nullptr;
  const uint8_t* uid_ = nullptr;
  ParamCallback param_cb_ = nullptr;
  ParamCallback push_cb_ = nullptr;
  LogCallback log_cb_ = nullptr;
  void (*on_data_)(NodeHandle_*, const Message&) = nullptr;  // topic data: only with a subscriber
  Handler on_request_ = nullptr;
  Handler on_response_ = nullptr;
  Handler on_param_ = nullptr;
  void* sync_out_ = nullptr;  // blocking getParam: where the values go
  bool (*sync_copy_)(void*, const ParamValue&, uint16_t) = nullptr;
  void* call_res_ = nullptr;
  Entry* call_entry_ = nullptr;
  uint32_t board_ref_ = 0, host_sec_ = 0, host_nsec_ = 0;  // time sync reference pair
  Reassembler<kReassembly> reasm_{};
  FrameDecoder<Profile::kMtu, false, kAckInData, kFixedMtu> dec_{};
  uint8_t tx_[Profile::kTxBuffer] = {};

  // kAnswerOwed: a service request was taken back (no room for its answer); until it comes
  // again, messages of the board's own do not take the transmit buffer (sendOn)
  enum Flag : uint8_t { kFixed = 1, kInInput = 2, kTimeSynced = 4, kLead = 8, kAnswerOwed = 16 };
  bool flag(uint8_t f) const { return (flags_ & f) != 0; }
  /** Calls on the services' channels have one-byte heads: both ends have SERVICE_CHANNELS and
   * SHORT_CALLS (2.8; SHORT_CALLS alone changes nothing). */
  bool shortCalls() const {
    return (features_ & (control::Features::SERVICE_CHANNELS | control::Features::SHORT_CALLS)) ==
           (control::Features::SERVICE_CHANNELS | control::Features::SHORT_CALLS);
  }
  void setFlag(uint8_t f, bool on) { flags_ = static_cast<uint8_t>(on ? flags_ | f : flags_ & ~f); }
};

#if defined(HWBRIDGE_BOARD_STM32F4)
}  // namespace hwbridge
#include "hardware_stm32f4.h"
namespace hwbridge {
/** The default node on a bare STM32F4 (hwbridge firmware build --board stm32f405): USART1. */
typedef NodeHandle_<Stm32f4Hardware> NodeHandle;
#elif defined(HWBRIDGE_BOARD_NRF51)
}  // namespace hwbridge
#include "hardware_nrf51.h"
namespace hwbridge {
/** The default node on a bare nRF51 (hwbridge firmware build --board microbit): UART0. */
typedef NodeHandle_<Nrf51Hardware> NodeHandle;
#elif defined(ARDUINO)
}  // namespace hwbridge
#include "hardware_arduino.h"
namespace hwbridge {
/** The default node: Arduino Serial, HelloWorldProfile. */
typedef NodeHandle_<ArduinoHardware> NodeHandle;
#elif !defined(__AVR__)
}  // namespace hwbridge
#include "hardware_posix.h"
namespace hwbridge {
/** The default node on a host build: a pseudo-terminal (its path printed at init). */
typedef NodeHandle_<PosixHardware> NodeHandle;
#endif

}  // namespace hwbridge

#include "node_impl.h"

#endif  // HWBRIDGE_NODE_H
