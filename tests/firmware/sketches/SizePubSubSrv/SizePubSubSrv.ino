// The footprint floor's publisher + subscriber + service sketch (issue 14), as rosserial's:
// a std_msgs/String publisher, a std_msgs/Bool subscriber (the LED), a std_srvs/Trigger server.
#include <HwBridge.h>
#include <std_msgs/Bool.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");

void on_led(const std_msgs::Bool& m) { digitalWrite(LED_BUILTIN, m.data ? HIGH : LOW); }
hwbridge::Subscriber<std_msgs::Bool> led("led", &on_led);

void on_reset(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  res.success = true;
  res.message.assign("done");
}
hwbridge::ServiceServer<std_srvs::Trigger> reset("reset", &on_reset);

void setup() {
  pinMode(LED_BUILTIN, OUTPUT);
  nh.initNode(115200, "uno");
  nh.advertise(chatter);
  nh.subscribe(led);
  nh.advertiseService(reset);
}

void loop() {
  str_msg.data.assign("hello world!");
  chatter.publish(str_msg);
  nh.spinOnce();
  delay(1000);
}
