// The footprint floor's hello world (issue 14): one best-effort publisher of std_msgs/String,
// as rosserial's HelloWorld. Built for the Uno by tests/firmware/test_session_size.py.
#include <HwBridge.h>
#include <std_msgs/String.h>

hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");

void setup() {
  nh.initNode(115200, "uno");
  nh.advertise(chatter);
}

void loop() {
  str_msg.data.assign("hello world!");
  chatter.publish(str_msg);
  nh.spinOnce();
  delay(1000);
}
