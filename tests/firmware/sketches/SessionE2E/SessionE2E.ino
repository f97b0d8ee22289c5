// The end-to-end sketch of tests/firmware/test_session_e2e.py, built with --board host:
// a reliable counter (std_msgs/Int32 on `counter`, 0, 1, 2, ... every 20 ms while connected, each
// number once), a best-effort `chatter`, a subscriber `cmd` whose messages are logged back, a
// service `ping` (std_srvs/Trigger: "pong N"), a client of the host's `check` (std_srvs/Trigger,
// called when `cmd` says "ask", its outcome logged), the parameter `rate` read (blocking) after
// each connection, `gain` subscribed (pushed changes logged), and logs.
#include <HwBridge.h>
#include <std_msgs/Int32.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

hwbridge::NodeHandle_<hwbridge::PosixHardware, hwbridge::ComfortableProfile> nh;
std_msgs::Int32 count_msg;
std_msgs::String chat_msg;
hwbridge::Publisher<std_msgs::Int32> counter("counter", true);
hwbridge::Publisher<std_msgs::String> chatter("chatter");

char got[40];
bool have_got = false;
bool ask = false;
void on_cmd(const std_msgs::String& m) {
  snprintf(got, sizeof got, "got %s", m.data.c_str());
  have_got = true;
  if (strcmp(m.data.c_str(), "ask") == 0) ask = true;  // the call itself goes from loop()
}
hwbridge::Subscriber<std_msgs::String> cmd("cmd", &on_cmd);
hwbridge::ServiceClient<std_srvs::Trigger> check("check");

uint16_t pings = 0;
void on_ping(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  char text[16];
  snprintf(text, sizeof text, "pong %u", ++pings);
  res.success = true;
  res.message.assign(text);
}
hwbridge::ServiceServer<std_srvs::Trigger> ping("ping", &on_ping);

char pushed[40];
bool have_pushed = false;
void on_gain(const hwbridge::ParamValue& v) {
  if (v.ok()) {
    snprintf(pushed, sizeof pushed, "gain %s %ld", v.request_id ? "is" : "now", static_cast<long>(v.asInt()));
    have_pushed = true;
  }
}

bool was_connected = false;
unsigned long last_ms = 0;

void setup() {
  nh.initNode(115200, "e2e", "1.0");
  nh.advertise(counter);
  nh.advertise(chatter);
  nh.subscribe(cmd);
  nh.advertiseService(ping);
  nh.serviceClient(check);
}

void loop() {
  nh.spinOnce();
  if (!nh.connected()) {
    was_connected = false;
    return;
  }
  if (!was_connected) {
    was_connected = true;
    int32_t rate = -1;
    char text[40];
    if (nh.getParam("rate", &rate)) {
      snprintf(text, sizeof text, "rate is %ld", static_cast<long>(rate));
    } else {
      snprintf(text, sizeof text, "rate not set");
    }
    nh.logInfo(text);
    nh.requestParam("gain", hwbridge::kParamInt32, &on_gain, true);
  }
  if (have_got && nh.logWarn(got)) have_got = false;
  if (ask && !have_got) {
    ask = false;
    std_srvs::Trigger::Request req;
    std_srvs::Trigger::Response res;
    const uint8_t status = check.call(req, res, 3000);
    char text[72];
    snprintf(text, sizeof text, "asked: status %u, %s '%s'", status, res.success ? "success" : "no success",
             status == hwbridge::kCallOk ? res.message.c_str() : "");
    nh.logInfo(text);
  }
  if (have_pushed && nh.logInfo(pushed)) have_pushed = false;
  if (millis() - last_ms >= 20) {
    last_ms = millis();
    if (counter.publish(count_msg)) ++count_msg.data;
    chat_msg.data.assign("hi");
    chatter.publish(chat_msg);
  }
}
