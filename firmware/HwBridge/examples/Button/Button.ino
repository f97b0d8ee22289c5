// Button: a publisher of a push button's state. A button between pin 7 and GND (the internal
// pull-up holds the pin high): std_msgs/Bool on `pushed`, true while it is pressed, sent on the
// reliable stream at each (debounced) change and once a second besides. The built-in LED shows
// the state.
//
//   hwbridge topic echo /pushed
#include <HwBridge.h>
#include <std_msgs/Bool.h>

const uint8_t kButtonPin = 7;
const unsigned long kDebounceMs = 20;

hwbridge::NodeHandle nh;
std_msgs::Bool pushed_msg;
hwbridge::Publisher<std_msgs::Bool> pushed("pushed", true);  // reliable: no change lost

bool stable = false;        // debounced state (true: pressed)
bool last_reading = false;
unsigned long changed_ms = 0;
unsigned long published_ms = 0;

void setup() {
  pinMode(kButtonPin, INPUT_PULLUP);
  pinMode(LED_BUILTIN, OUTPUT);
  nh.initNode(115200, "button");
  nh.advertise(pushed);
}

void loop() {
  bool reading = digitalRead(kButtonPin) == LOW;
  unsigned long now = millis();
  if (reading != last_reading) {
    last_reading = reading;
    changed_ms = now;
  }
  bool publish = now - published_ms >= 1000;
  if (reading != stable && now - changed_ms >= kDebounceMs) {
    stable = reading;
    digitalWrite(LED_BUILTIN, stable ? HIGH : LOW);
    publish = true;
  }
  if (publish && nh.connected()) {
    pushed_msg.data = stable;
    if (pushed.publish(pushed_msg)) published_ms = now;
  }
  nh.spinOnce();
}
