// One board of tools/bench/soak.py: the HwBridge library built for the host
// (`python -m hwbridge firmware build tools/bench/SoakBoard --board host`), so that the soak
// bench measures the bridge against boards as cheap as real ones. Host builds only (it reads its
// settings from the environment and its commands from stdin).
//
// Settings (environment): SOAK_INDEX (board NN: name "bNN"), SOAK_TOPICS (10), SOAK_RELIABLE
// (2: the first topics go on the reliable stream), SOAK_RATE (50: Hz per topic, may be fractional); the link is
// argv[1] (e.g. listen://127.0.0.1:PORT: the bridge dials the board).
//
// The board advertises soak/bNN/t0 .. t{TOPICS-1} (std_msgs/String) and serves soak/bNN/trigger
// (std_srvs/Trigger). Once told "go" it publishes every topic RATE times a second, each message
// "<seq> <CLOCK_MONOTONIC ns>" (seq counts that topic's accepted messages from 0). Commands, one
// a line on stdin, each answered by one line on stdout:
//   status -> 1 when the session is up, else 0     go -> going (publishing starts)
//   stop   -> one JSON line (below); publishing stops, the node keeps spinning so that what the
//             reliable window holds still goes out
//   quit (or end of stdin) -> the program exits
// The JSON line: {"boards": {"bNN": {"published": [per topic], "refused": [per topic: not sent,
// because publish() returned false or would have waited (nh.txReady() false: the reliable
// window full)], "served": N, "link_losses": N, "peer_resets": N, "sessions": N}},
// "late_ticks": N} (a late tick: the loop fell a whole period behind; the schedule restarts from
// now instead of publishing the missed ticks in a burst).
#include <HwBridge.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

#include <errno.h>
#include <new>
#include <poll.h>
#include <sys/ioctl.h>

namespace {

// Sized for the soak: 10+ topics (the table is a linked list: up to 255 entries), messages of
// about 30 bytes (one frame, no fragments), and a reliable window of 16 (the bridge's own) so
// that two reliable topics at 50 Hz wait for an ACK only when the bridge is 160 ms behind
// (ComfortableProfile's window of 2: at each ACK slower than 20 ms).
struct SoakProfile {
  static const uint16_t kMtu = 64;
  static const uint16_t kMaxMessage = 64;
  static const uint8_t kWindow = 16;
  static const uint16_t kTxBuffer = 64;
  static const uint8_t kFeatures = 3;
  static const uint16_t kTimeSyncMs = 0;
  static const uint16_t kParamTimeoutMs = 2000;
  static const uint16_t kServiceTimeoutMs = 5000;
  static const bool kFixedRto = false;
};

const int kMaxTopics = 64;
const uint32_t kMaxNapUs = 10000;  // the longest poll() between two spinOnce() calls

typedef hwbridge::Publisher<std_msgs::String> StringPublisher;

uint64_t now_ns() {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000000u + static_cast<uint64_t>(ts.tv_nsec);
}

/** The POSIX link, noting when the board last read a byte from the bridge (for the account of
 * each link loss below). */
class TracingHardware : public hwbridge::PosixHardware {
 public:
  int read() {
    const int c = hwbridge::PosixHardware::read();
    if (c >= 0) last_byte_ns = now_ns();
    return c;
  }
  /** Bytes waiting in the kernel's socket buffer, not read yet. */
  int pending() {
    int n = 0;
    if (fd() < 0 || ioctl(fd(), FIONREAD, &n) != 0) return -1;
    return n;
  }
  uint64_t last_byte_ns = 0;
};

hwbridge::NodeHandle_<TracingHardware, SoakProfile> nh;
std_msgs::String message;
char board[8];
uint8_t uid[4];
char names[kMaxTopics][32];
char service_name[32];
alignas(StringPublisher) unsigned char storage[kMaxTopics][sizeof(StringPublisher)];
StringPublisher* publishers[kMaxTopics];
uint32_t published[kMaxTopics];
uint32_t refused[kMaxTopics];
uint32_t seq[kMaxTopics];
uint32_t served = 0;
uint32_t late_ticks = 0;
int topics = 10;
long period_us = 20000;
bool publishing = false;
uint64_t next_tick_us = 0;
char command[64];
size_t command_len = 0;

// The account of each link loss this board declared: how long since it last read a byte from the
// bridge, how long its own loop had not run just before (a board starved of the CPU), and the
// bytes waiting unread in its socket.
const int kMaxLossNotes = 8;
struct LossNote {
  uint32_t since_byte_ms;
  uint32_t loop_gap_ms;
  int pending;
};
LossNote loss_notes[kMaxLossNotes];
int loss_count = 0;
unsigned last_link_losses = 0;
uint64_t last_loop_ns = 0;
uint32_t max_loop_gap_ms = 0;
uint32_t own_stalls = 0;  // loop gaps above 200 ms (PROTOCOL.md 2.9's bound at the defaults)

long setting(const char* name, long fallback, long low, long high) {
  const char* text = getenv(name);
  if (text == nullptr || text[0] == 0) return fallback;
  char* end = nullptr;
  errno = 0;
  const long value = strtol(text, &end, 10);
  if (errno != 0 || *end != 0 || value < low || value > high) {
    fprintf(stderr, "SoakBoard: %s=%s: expected an integer from %ld to %ld\n", name, text, low, high);
    exit(2);
  }
  return value;
}

double rate_setting(const char* name, double fallback) {
  const char* text = getenv(name);
  if (text == nullptr || text[0] == 0) return fallback;
  char* end = nullptr;
  const double value = strtod(text, &end);
  if (*end != 0 || !(value > 0.0 && value <= 100000.0)) {
    fprintf(stderr, "SoakBoard: %s=%s: expected a rate in Hz above 0, at most 100000\n", name, text);
    exit(2);
  }
  return value;
}

void on_trigger(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  ++served;
  res.success = true;
  res.message.assign("ok");
}
hwbridge::ServiceServer<std_srvs::Trigger> trigger(service_name, &on_trigger);

void print_counts() {
  printf("{\"boards\": {\"%s\": {\"published\": [", board);
  for (int j = 0; j < topics; ++j) printf("%s%lu", j ? ", " : "", static_cast<unsigned long>(published[j]));
  printf("], \"refused\": [");
  for (int j = 0; j < topics; ++j) printf("%s%lu", j ? ", " : "", static_cast<unsigned long>(refused[j]));
  const hwbridge::NodeStats& stats = nh.stats();
  printf("], \"served\": %lu, \"link_losses\": %u, \"peer_resets\": %u, \"sessions\": %u,",
         static_cast<unsigned long>(served), static_cast<unsigned>(stats.link_losses),
         static_cast<unsigned>(stats.peer_resets), static_cast<unsigned>(stats.sessions));
  printf(" \"stalls\": %u, \"own_stalls\": %lu, \"max_loop_gap_ms\": %lu, \"losses\": [",
         static_cast<unsigned>(stats.stalls), static_cast<unsigned long>(own_stalls),
         static_cast<unsigned long>(max_loop_gap_ms));
  for (int i = 0; i < loss_count && i < kMaxLossNotes; ++i) {
    printf("%s{\"since_byte_ms\": %lu, \"loop_gap_ms\": %lu, \"pending\": %d}", i ? ", " : "",
           static_cast<unsigned long>(loss_notes[i].since_byte_ms),
           static_cast<unsigned long>(loss_notes[i].loop_gap_ms), loss_notes[i].pending);
  }
  printf("]}}, \"late_ticks\": %lu}\n", static_cast<unsigned long>(late_ticks));
}

void run_command(const char* text) {
  if (strcmp(text, "status") == 0) {
    printf("%d\n", nh.connected() ? 1 : 0);
  } else if (strcmp(text, "go") == 0) {
    publishing = true;
    next_tick_us = now_ns() / 1000u;
    printf("going\n");
  } else if (strcmp(text, "stop") == 0) {
    publishing = false;
    print_counts();
  } else if (strcmp(text, "quit") == 0) {
    exit(0);
  } else if (text[0] != 0) {
    printf("unknown command: %s\n", text);
  }
}

/** Reads what stdin has (never blocks) and runs each complete line; end of stdin: exit. */
void read_commands() {
  char chunk[64];
  const ssize_t n = read(0, chunk, sizeof chunk);
  if (n == 0) exit(0);
  for (ssize_t i = 0; i < n; ++i) {
    if (chunk[i] == '\n') {
      command[command_len] = 0;
      run_command(command);
      command_len = 0;
    } else if (command_len + 1 < sizeof command) {
      command[command_len++] = chunk[i];
    }
  }
}

void publish_all() {
  for (int j = 0; j < topics; ++j) {
    char text[32];
    snprintf(text, sizeof text, "%lu %llu", static_cast<unsigned long>(seq[j]),
             static_cast<unsigned long long>(now_ns()));
    message.data.assign(text);
    // a reliable message waiting for a window slot would make publish() spin for up to 250 ms
    // (a busy loop on a host): read what came (the ACK may be there), else count it refused
    if (!nh.txReady()) nh.spinOnce();
    if (nh.txReady() && publishers[j]->publish(message)) {
      ++published[j];
      ++seq[j];
    } else {
      ++refused[j];
    }
  }
}

}  // namespace

void setup() {
  const long index = setting("SOAK_INDEX", 0, 0, 99);
  topics = static_cast<int>(setting("SOAK_TOPICS", 10, 1, kMaxTopics));
  const long reliable = setting("SOAK_RELIABLE", 2, 0, kMaxTopics);
  period_us = static_cast<long>(1e6 / rate_setting("SOAK_RATE", 50.0) + 0.5);
  snprintf(board, sizeof board, "b%02ld", index);
  for (int i = 0; i < 4; ++i) uid[i] = static_cast<uint8_t>(index >> (8 * i));
  snprintf(service_name, sizeof service_name, "soak/%s/trigger", board);
  nh.setUniqueId(uid, sizeof uid);
  nh.initNode(115200, board, "soak");
  if (nh.getHardware().error()[0] != 0) exit(1);  // the link did not open (the reason is on stderr)
  for (int j = 0; j < topics; ++j) {
    snprintf(names[j], sizeof names[j], "soak/%s/t%d", board, j);
    publishers[j] = new (storage[j]) StringPublisher(names[j], j < reliable);
    nh.advertise(*publishers[j]);
  }
  nh.advertiseService(trigger);
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
  printf("ready\n");
}

void loop() {
  const uint64_t loop_ns = now_ns();
  const uint32_t gap_ms = last_loop_ns ? static_cast<uint32_t>((loop_ns - last_loop_ns) / 1000000u) : 0;
  last_loop_ns = loop_ns;
  if (gap_ms > max_loop_gap_ms) max_loop_gap_ms = gap_ms;
  if (gap_ms > 200) ++own_stalls;
  nh.spinOnce();
  if (static_cast<unsigned>(nh.stats().link_losses) != last_link_losses) {
    last_link_losses = static_cast<unsigned>(nh.stats().link_losses);
    TracingHardware& hw = nh.getHardware();
    if (loss_count < kMaxLossNotes) {
      LossNote& note = loss_notes[loss_count];
      note.since_byte_ms = hw.last_byte_ns ? static_cast<uint32_t>((now_ns() - hw.last_byte_ns) / 1000000u) : 0;
      note.loop_gap_ms = gap_ms;
      note.pending = hw.pending();
    }
    ++loss_count;
  }
  read_commands();
  uint64_t now_us = now_ns() / 1000u;
  if (publishing && now_us >= next_tick_us) {
    publish_all();
    next_tick_us += static_cast<uint64_t>(period_us);
    now_us = now_ns() / 1000u;
    if (now_us >= next_tick_us + static_cast<uint64_t>(period_us)) {  // a whole period behind
      ++late_ticks;
      next_tick_us = now_us + static_cast<uint64_t>(period_us);
    }
  }
  // Sleep until input arrives (the bridge's bytes or a command) or the next tick, at most
  // kMaxNapUs: a real board spins, but 32 host programs waking every 0.2 ms would take a large
  // share of the machine the bridge runs on.
  uint64_t nap_us = kMaxNapUs;
  if (publishing) nap_us = next_tick_us > now_us ? next_tick_us - now_us : 0;
  if (nap_us > kMaxNapUs) nap_us = kMaxNapUs;
  struct pollfd fds[2];
  fds[0].fd = 0;
  fds[0].events = POLLIN;
  fds[1].fd = nh.getHardware().fd();
  fds[1].events = POLLIN;
  poll(fds, fds[1].fd >= 0 ? 2 : 1, static_cast<int>(nap_us / 1000u));
}
