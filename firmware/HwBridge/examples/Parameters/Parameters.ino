// Parameters: the board reads its settings from the host's parameter server and follows changes.
//
// At each connection it reads `gains` (a list of 3 numbers) with the blocking getParam(), as
// rosserial sketches do, and asks for `blink_period_ms` with requestParam(..., subscribe):
// the answer, and every later change the host pushes, arrive in on_period(). The built-in LED
// blinks at that period; each value is logged to the host.
//
//   hwbridge param set /blink_period_ms 100      # (in the board's namespace)
//   hwbridge param set /gains '[1.0, 0.5, 0.01]'
#include <HwBridge.h>

hwbridge::NodeHandle nh;

long period_ms = 500;
float gains[3] = {1.0f, 0.0f, 0.0f};
bool configured = false;
unsigned long toggled_ms = 0;

void on_period(const hwbridge::ParamValue& value) {
  char line[48];
  if (value.ok() && value.asInt() > 0) {
    period_ms = value.asInt();
    snprintf(line, sizeof line, "blink_period_ms = %ld", period_ms);
    nh.logInfo(line);
  } else if (value.status == hwbridge::kParamNotFound) {
    nh.logWarn("blink_period_ms is not set: blinking every 500 ms");
  }
}

void configure() {
  if (nh.getParam("gains", gains, 3)) {
    char line[48];
    // %f is not in AVR's printf: milli-units as integers.
    snprintf(line, sizeof line, "gains (x1000) = %ld %ld %ld", static_cast<long>(gains[0] * 1000),
             static_cast<long>(gains[1] * 1000), static_cast<long>(gains[2] * 1000));
    nh.logInfo(line);
  } else {
    nh.logWarn("gains: no list of 3 numbers; keeping 1 0 0");
  }
  nh.requestParam("blink_period_ms", hwbridge::kParamInt32, &on_period, true);
}

void setup() {
  pinMode(LED_BUILTIN, OUTPUT);
  nh.initNode(115200, "parameters");
}

void loop() {
  if (nh.connected() && !configured) {
    configured = true;  // once per session: a new session asks again
    configure();
  } else if (!nh.connected()) {
    configured = false;
  }
  if (millis() - toggled_ms >= static_cast<unsigned long>(period_ms)) {
    toggled_ms = millis();
    digitalWrite(LED_BUILTIN, !digitalRead(LED_BUILTIN));
  }
  nh.spinOnce();
}
