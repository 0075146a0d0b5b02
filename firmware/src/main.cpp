// impactsense firmware for the Arduino Nano 33 BLE (nRF52840, Arduino mbed core).
//
// Thin board layer: SAADC scan over A0..A3 (AIN2, AIN3, AIN6, AIN5), sampled by TIMER4 through PPI,
// EasyDMA into two buffers; USB serial and a BLE GATT service. Everything else is impactapp (portable,
// tested on the host and under qemu).
//
// Acquisition (nRF52840 PS v1.7, SAADC / TIMER / PPI chapters):
//   TIMER4 COMPARE[0] (every 16 MHz / fs ticks, short COMPARE0 -> CLEAR) --PPI ch A--> SAADC TASKS_SAMPLE:
//   one SAMPLE converts all four enabled channels back to back (scan), TACQ 3 us + <= 2 us conversion each,
//   so channel c is read c * 5 us after channel 0 (impactapp::kScanStepUs, removed by the core) and
//   4 x 50 kHz = 200 ksps is the converter's ceiling.
//   SAADC EVENTS_END --PPI ch B--> SAADC TASKS_START: the next buffer starts at once; RESULT.PTR is
//   double-buffered, so the STARTED interrupt points it at the other buffer ahead of time.
//   The END interrupt hands the full buffer to loop(), which calls App::on_samples().
//
// Memory: 2 x kDmaFrames x 4 int16 = 4 KB of DMA buffers + impactapp::App (~21 KB, impactapp.h). No heap
// after setup(). Timing: a DMA buffer is 256 frames = 5.12 ms at 50 kHz; loop() must take a buffer within
// that (the event processing runs inside on_samples; see the cost budget in impactapp.h).
#include <Arduino.h>
#include <ArduinoBLE.h>

#include "impactapp.h"
#include "impactapp_models.h"
#include "nrf.h"

namespace {

constexpr int kDmaFrames = 256;
constexpr uint32_t kTimerHz = 16000000u;
constexpr uint8_t kPpiSample = 10;   // PPI channels not used by the Arduino mbed core
constexpr uint8_t kPpiRestart = 11;
// A0, A1, A2, A3 of the Nano 33 BLE: P0.04 = AIN2, P0.05 = AIN3, P0.30 = AIN6, P0.29 = AIN5.
const uint32_t kPsel[4] = {SAADC_CH_PSELP_PSELP_AnalogInput2, SAADC_CH_PSELP_PSELP_AnalogInput3,
                           SAADC_CH_PSELP_PSELP_AnalogInput6, SAADC_CH_PSELP_PSELP_AnalogInput5};

int16_t g_dma[2][kDmaFrames * 4] __attribute__((aligned(4)));
volatile uint8_t g_next = 0;        // the buffer the SAADC is filling (set at each STARTED)
volatile int8_t g_ready = -1;       // buffer completed and waiting for loop()
volatile uint32_t g_overruns = 0;   // buffers loop() was too late for

const char* kServiceUuid = "6e5a0001-8a3c-4b8e-9d2f-1c0ffee10001";
BLEService g_service(kServiceUuid);
BLECharacteristic g_report("6e5a0002-8a3c-4b8e-9d2f-1c0ffee10001", BLERead | BLENotify,
                           impactlink::kBlePayload, true);
BLECharacteristic g_config("6e5a0003-8a3c-4b8e-9d2f-1c0ffee10001", BLEWrite | BLEWriteWithoutResponse, 20);

void saadc_irq() {
  // END before STARTED: END of buffer k triggers (PPI) the START of k+1 at once, so both may be pending.
  if (NRF_SAADC->EVENTS_END) {
    NRF_SAADC->EVENTS_END = 0;
    if (g_ready >= 0) ++g_overruns;
    g_ready = static_cast<int8_t>(g_next);  // after a STARTED, g_next names the buffer that was filling
  }
  if (NRF_SAADC->EVENTS_STARTED) {
    NRF_SAADC->EVENTS_STARTED = 0;
    // The SAADC latched RESULT.PTR (buffer g_next ^ 1 is filling now); point it at the other one.
    NRF_SAADC->RESULT.PTR = reinterpret_cast<uint32_t>(g_dma[g_next]);
    g_next ^= 1;
  }
}

void timer_rate(uint32_t fs_hz) {
  NRF_TIMER4->TASKS_STOP = 1;
  NRF_TIMER4->TASKS_CLEAR = 1;
  NRF_TIMER4->CC[0] = kTimerHz / fs_hz;
  NRF_TIMER4->TASKS_START = 1;
}

void acquisition_begin(uint32_t fs_hz) {
  NRF_SAADC->ENABLE = SAADC_ENABLE_ENABLE_Disabled << SAADC_ENABLE_ENABLE_Pos;
  NRF_SAADC->RESOLUTION = SAADC_RESOLUTION_VAL_12bit << SAADC_RESOLUTION_VAL_Pos;
  NRF_SAADC->OVERSAMPLE = SAADC_OVERSAMPLE_OVERSAMPLE_Bypass << SAADC_OVERSAMPLE_OVERSAMPLE_Pos;
  NRF_SAADC->SAMPLERATE = SAADC_SAMPLERATE_MODE_Task << SAADC_SAMPLERATE_MODE_Pos;
  for (int c = 0; c < 8; ++c) {
    NRF_SAADC->CH[c].PSELP = SAADC_CH_PSELP_PSELP_NC;
    NRF_SAADC->CH[c].PSELN = SAADC_CH_PSELN_PSELN_NC;
  }
  for (int c = 0; c < 4; ++c) {
    // Single-ended, gain 1/4 of VDD/4: full scale = VDD (the PZT bias sits at VDD/2 = 2048 counts).
    NRF_SAADC->CH[c].CONFIG = (SAADC_CH_CONFIG_RESP_Bypass << SAADC_CH_CONFIG_RESP_Pos) |
                              (SAADC_CH_CONFIG_RESN_Bypass << SAADC_CH_CONFIG_RESN_Pos) |
                              (SAADC_CH_CONFIG_GAIN_Gain1_4 << SAADC_CH_CONFIG_GAIN_Pos) |
                              (SAADC_CH_CONFIG_REFSEL_VDD1_4 << SAADC_CH_CONFIG_REFSEL_Pos) |
                              (SAADC_CH_CONFIG_TACQ_3us << SAADC_CH_CONFIG_TACQ_Pos) |
                              (SAADC_CH_CONFIG_MODE_SE << SAADC_CH_CONFIG_MODE_Pos) |
                              (SAADC_CH_CONFIG_BURST_Disabled << SAADC_CH_CONFIG_BURST_Pos);
    NRF_SAADC->CH[c].PSELP = kPsel[c] << SAADC_CH_PSELP_PSELP_Pos;  // enabling PSELP enables the channel
  }
  NRF_SAADC->RESULT.PTR = reinterpret_cast<uint32_t>(g_dma[0]);
  NRF_SAADC->RESULT.MAXCNT = kDmaFrames * 4;  // whole scans only, so frames never straddle buffers
  g_next = 1;  // the first STARTED latches buffer 0 and sets PTR to buffer 1
  NRF_SAADC->EVENTS_STARTED = 0;
  NRF_SAADC->EVENTS_END = 0;
  NRF_SAADC->INTENSET = SAADC_INTENSET_STARTED_Msk | SAADC_INTENSET_END_Msk;
  NVIC_SetVector(SAADC_IRQn, reinterpret_cast<uint32_t>(&saadc_irq));
  NVIC_SetPriority(SAADC_IRQn, 2);
  NVIC_EnableIRQ(SAADC_IRQn);
  NRF_SAADC->ENABLE = SAADC_ENABLE_ENABLE_Enabled << SAADC_ENABLE_ENABLE_Pos;

  NRF_SAADC->EVENTS_CALIBRATEDONE = 0;  // offset calibration once at start-up
  NRF_SAADC->TASKS_CALIBRATEOFFSET = 1;
  while (!NRF_SAADC->EVENTS_CALIBRATEDONE) {
  }
  NRF_SAADC->EVENTS_CALIBRATEDONE = 0;

  NRF_TIMER4->MODE = TIMER_MODE_MODE_Timer << TIMER_MODE_MODE_Pos;
  NRF_TIMER4->BITMODE = TIMER_BITMODE_BITMODE_32Bit << TIMER_BITMODE_BITMODE_Pos;
  NRF_TIMER4->PRESCALER = 0;  // 16 MHz
  NRF_TIMER4->SHORTS = TIMER_SHORTS_COMPARE0_CLEAR_Msk;

  NRF_PPI->CH[kPpiSample].EEP = reinterpret_cast<uint32_t>(&NRF_TIMER4->EVENTS_COMPARE[0]);
  NRF_PPI->CH[kPpiSample].TEP = reinterpret_cast<uint32_t>(&NRF_SAADC->TASKS_SAMPLE);
  NRF_PPI->CH[kPpiRestart].EEP = reinterpret_cast<uint32_t>(&NRF_SAADC->EVENTS_END);
  NRF_PPI->CH[kPpiRestart].TEP = reinterpret_cast<uint32_t>(&NRF_SAADC->TASKS_START);
  NRF_PPI->CHENSET = (1u << kPpiSample) | (1u << kPpiRestart);

  NRF_SAADC->TASKS_START = 1;
  timer_rate(fs_hz);
}

class BoardHal : public impactapp::Hal {
 public:
  void write(const uint8_t* data, size_t n) override {
    if (Serial) Serial.write(data, n);
  }
  void notify(const uint8_t* payload, size_t n) override {
    if (BLE.connected()) g_report.writeValue(payload, static_cast<int>(n));
  }
  bool apply_rate(uint32_t fs_hz) override {
    if (fs_hz < impactapp::kMinRateHz || fs_hz > impactapp::kMaxRateHz) return false;
    timer_rate(fs_hz);
    return true;
  }
};

BoardHal g_hal;
impactapp::TableModels g_models = impactapp::exported_models();
impactapp::App g_app(g_hal, &g_models, impactapp::exported_config(impactapp::AppConfig()));
uint8_t g_rx[64];

}  // namespace

void setup() {
  Serial.begin(115200);  // USB CDC: the baud rate is nominal
  if (BLE.begin()) {
    BLE.setLocalName("impactsense");
    BLE.setAdvertisedService(g_service);
    g_service.addCharacteristic(g_report);
    g_service.addCharacteristic(g_config);
    BLE.addService(g_service);
    BLE.advertise();
  }
  acquisition_begin(g_app.config().fs_hz);
}

void loop() {
  const int8_t ready = g_ready;
  if (ready >= 0) {
    g_app.on_samples(g_dma[ready], kDmaFrames);
    g_ready = -1;
  }
  int n = 0;
  while (Serial && Serial.available() > 0 && n < static_cast<int>(sizeof(g_rx))) g_rx[n++] = Serial.read();
  if (n > 0) g_app.on_rx(g_rx, static_cast<size_t>(n));
  BLE.poll();
  if (g_config.written()) g_app.on_rx(g_config.value(), static_cast<size_t>(g_config.valueLength()));
}
