// ServiceServer: the board serves std_srvs/SetBool on `set_led` (switches the built-in LED and
// says what it did) and std_srvs/Trigger on `count` (how many calls so far).
//
//   hwbridge service call /set_led '{data: true}'
//   hwbridge service call /count '{}'
// A service server gains from ACKs carried in data frames (no ACK frame per call, PROTOCOL.md
// 2.4): on AVR the library builds them only when asked, as they cost some 300 B of flash.
#define HWBRIDGE_ACK_IN_DATA 1
#include <HwBridge.h>
#include <std_srvs/SetBool.h>
#include <std_srvs/Trigger.h>

hwbridge::NodeHandle nh;
uint16_t calls = 0;

void on_set_led(const std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
  digitalWrite(LED_BUILTIN, req.data ? HIGH : LOW);
  ++calls;
  res.success = true;
  res.message.assign(req.data ? "LED on" : "LED off");
}

void on_count(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  ++calls;
  // "N calls", written digit by digit: snprintf would do it too, with some 1.5 KB of formatting
  // code on an AVR and some 2000 cycles a call
  char text[12];
  uint8_t k = 0;
  uint16_t n = calls;
  do text[k++] = static_cast<char>('0' + n % 10); while ((n /= 10) != 0);
  for (uint8_t i = 0; i < k / 2; ++i) {  // the digits came lowest first
    const char c = text[i];
    text[i] = text[k - 1 - i];
    text[k - 1 - i] = c;
  }
  strcpy(text + k, " calls");
  res.success = true;
  res.message.assign(text);
}

hwbridge::ServiceServer<std_srvs::SetBool> set_led("set_led", &on_set_led);
hwbridge::ServiceServer<std_srvs::Trigger> count("count", &on_count);

void setup() {
  pinMode(LED_BUILTIN, OUTPUT);
  nh.initNode(115200, "service_server");
  nh.advertiseService(set_led);
  nh.advertiseService(count);
}

void loop() {
  nh.spinOnce();
}
