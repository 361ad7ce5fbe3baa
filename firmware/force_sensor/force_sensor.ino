// shelljax reference firmware: a fingertip force film (and an optional depth sensor) over USB serial.
//
// Wiring (5 V or 3.3 V boards alike):
//   Vcc ── force film ──┬── A0          the film on the high side of a divider, so the reading
//                       └── R_m ── GND  x = counts/1023 gives the conductance proxy c = x/(1-x).
//   R_m = 10 kΩ suits an Interlink FSR 402 up to ~25 N. Optional second channel: a linear
//   potentiometer / displacement sensor wiper on A1 (set DEPTH_CHANNEL to 1).
//
// Protocol version 1 (docs/sensing.md), 115200 baud, ASCII lines ending in '\n':
//   H,<firmware>,<version>,<rate_hz>,<adc_bits>,<n_channels>*<CS>   at boot and when the host sends '?'
//   S,<t_ms>,<raw0>[,<raw1>]*<CS>                                  one sample every 1000/RATE_HZ ms
// <CS>: XOR of every byte before '*', two uppercase hex digits. t_ms = millis() (wraps after ~49.7 days).

#include <Arduino.h>

#define FIRMWARE_NAME "shelljax-fsr"
#define FIRMWARE_VERSION "1.0.0"
#define RATE_HZ 100
#define ADC_BITS 10
#define FORCE_PIN A0
#define DEPTH_PIN A1
#define DEPTH_CHANNEL 0  // 1: also send A1 as raw1
#define OVERSAMPLE 4     // readings averaged per sample (noise / sqrt(4)), well within 10 ms

static const unsigned long PERIOD_US = 1000000UL / RATE_HZ;
static unsigned long next_us;

// Writes body + '*' + checksum + '\n'. body must not contain '*' or '\n'.
static void send_line(const char *body) {
  uint8_t cs = 0;
  for (const char *p = body; *p; ++p) cs ^= (uint8_t)*p;
  char tail[5];
  snprintf(tail, sizeof tail, "*%02X\n", cs);
  Serial.print(body);
  Serial.print(tail);
}

static void send_hello() {
  char body[64];
  snprintf(body, sizeof body, "H,%s,%s,%d,%d,%d", FIRMWARE_NAME, FIRMWARE_VERSION, RATE_HZ, ADC_BITS,
           DEPTH_CHANNEL ? 2 : 1);
  send_line(body);
}

static unsigned int read_average(uint8_t pin) {
  unsigned long sum = 0;
  for (uint8_t i = 0; i < OVERSAMPLE; ++i) sum += analogRead(pin);
  return (unsigned int)((sum + OVERSAMPLE / 2) / OVERSAMPLE);
}

void setup() {
  Serial.begin(115200);
  // Leonardo/Micro-style native USB: wait (briefly) for the host so the hello is not lost.
  unsigned long start = millis();
  while (!Serial && millis() - start < 2000) {
  }
  send_hello();
  next_us = micros();
}

void loop() {
  while (Serial.available() > 0) {
    if (Serial.read() == '?') send_hello();
  }
  // Fixed-rate schedule; unsigned subtraction keeps working across the micros() rollover.
  if ((long)(micros() - next_us) < 0) return;
  next_us += PERIOD_US;
  unsigned long t_ms = millis();
  unsigned int raw0 = read_average(FORCE_PIN);
  char body[48];
#if DEPTH_CHANNEL
  unsigned int raw1 = read_average(DEPTH_PIN);
  snprintf(body, sizeof body, "S,%lu,%u,%u", t_ms, raw0, raw1);
#else
  snprintf(body, sizeof body, "S,%lu,%u", t_ms, raw0);
#endif
  send_line(body);
}
