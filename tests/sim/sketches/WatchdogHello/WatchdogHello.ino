// WatchdogHello: HelloWorld that hangs on request. A std_msgs/Empty on `hang` arms the watchdog
// (15 ms) and stops calling spinOnce(): the chip resets, boots again and the bridge takes the
// new session, and "hello world!" comes again.
#include <HwBridge.h>
#include <avr/wdt.h>
#include <std_msgs/Empty.h>
#include <std_msgs/String.h>

hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");

void on_hang(const std_msgs::Empty&) {
  wdt_enable(WDTO_15MS);
  for (;;) {
  }
}
hwbridge::Subscriber<std_msgs::Empty> hang_sub("hang", &on_hang);

unsigned long last_ms = 0;

void setup() {
  MCUSR = 0;
  wdt_disable();  // a watchdog reset leaves it armed
  nh.initNode(115200, "watchdog_hello");
  nh.advertise(chatter);
  nh.subscribe(hang_sub);
  str_msg.data.assign("hello world!");
}

void loop() {
  if (millis() - last_ms >= 200) {
    last_ms = millis();
    chatter.publish(str_msg);
  }
  nh.spinOnce();
}
