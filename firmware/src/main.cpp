// impactsense firmware for the Arduino Nano 33 BLE (nRF52840, Arduino mbed core).
//
// Thin board layer: SAADC scan over A0..A3 (AIN2, AIN3, AIN6, AIN5), sampled by TIMER4 through PPI, EasyDMA
// into a ring of kDmaBuffers buffers; USB serial and a BLE GATT service. Everything else is impactapp
// (portable, tested on the host, in the emulator and under qemu).
//
// Acquisition (nRF52840 PS v1.7, SAADC / TIMER / PPI chapters):
//   TIMER4 COMPARE[0] (every 16 MHz / fs ticks, short COMPARE0 -> CLEAR) --PPI--> SAADC TASKS_SAMPLE: one
//   SAMPLE converts the four enabled channels back to back (scan). Per channel TACQ + tCONV: TACQ 3 us (the
//   source must settle the 2.5 pF sample capacitor to 12 bits in 3 us: <= 10 kOhm source impedance, the
//   front end in docs/board.md drives it through 1 kOhm) + tCONV <= 2 us = 5 us a channel (kScanStepUs),
//   20 us a scan; 4 x 50 kHz = one scan every 20 us: no margin at 50 kHz. The app's rate limit
//   (impactapp::kMaxRateHz) is 50 kHz only because the scan time is bounded by the datasheet's tCONV <= 2 us;
//   a SAMPLE task that arrives while a scan is running is ignored by the SAADC (a lost frame, not a shifted
//   one), so a slower tCONV shows as missing frames, never as a rotated channel order. At 40 kHz (25 us a
//   frame) the margin is 5 us a frame; docs/board.md says when to use it.
//   SAADC EVENTS_END --PPI--> SAADC TASKS_START: the next buffer starts at once; RESULT.PTR is double-buffered,
//   so the STARTED interrupt points it at the buffer after the one now filling.
//   The END interrupt counts completed buffers; loop() hands them to App::on_samples() in order.
//
// Buffer ring: buffer k % kDmaBuffers holds fill k. Fill t is overwritten when fill t + kDmaBuffers starts,
// i.e. at END(t + kDmaBuffers - 1). loop() takes fill t only while t >= g_filled - (kDmaBuffers - 2): then at
// least one whole buffer period (5.12 ms) remains before the SAADC comes back to it, far above the worst
// event (~1 ms). Older fills are skipped and counted as overruns (status frame). The ISR never touches what
// loop() is reading: it only advances a counter.
//
// Memory: kDmaBuffers x kDmaFrames x 4 int16 = 8 KB of DMA buffers + impactapp::App (~25 KB, impactapp.h).
// No heap after setup().
#include <Arduino.h>
#include <ArduinoBLE.h>

#include "USB/PluggableUSBSerial.h"
#include "impactapp.h"
#include "impactapp_models.h"
#include "nrf.h"
#include "nrfx_ppi.h"

namespace {

constexpr int kDmaFrames = 256;   // 5.12 ms at 50 kHz
constexpr int kDmaBuffers = 4;
constexpr uint32_t kTimerHz = 16000000u;
constexpr uint32_t kCpuHz = 64000000u;
// A0, A1, A2, A3 of the Nano 33 BLE: P0.04 = AIN2, P0.05 = AIN3, P0.30 = AIN6, P0.29 = AIN5.
const uint32_t kPsel[4] = {SAADC_CH_PSELP_PSELP_AnalogInput2, SAADC_CH_PSELP_PSELP_AnalogInput3,
                           SAADC_CH_PSELP_PSELP_AnalogInput6, SAADC_CH_PSELP_PSELP_AnalogInput5};

int16_t g_dma[kDmaBuffers][kDmaFrames * 4] __attribute__((aligned(4)));
int16_t g_scratch[8] __attribute__((aligned(4)));  // calibration's stray sample lands here (erratum 237)
volatile uint32_t g_filled = 0;   // buffers completed (END events) since start
volatile uint32_t g_started = 0;  // fills started (STARTED events)
uint32_t g_taken = 0;             // fills handed to the app (loop() only)
nrf_ppi_channel_t g_ppi_sample, g_ppi_restart;

const char* kServiceUuid = "6e5a0001-8a3c-4b8e-9d2f-1c0ffee10001";
BLEService g_service(kServiceUuid);
BLECharacteristic g_report("6e5a0002-8a3c-4b8e-9d2f-1c0ffee10001", BLERead | BLENotify,
                           impactlink::kBlePayload, true);
BLECharacteristic g_config("6e5a0003-8a3c-4b8e-9d2f-1c0ffee10001", BLEWrite | BLEWriteWithoutResponse, 20);

void saadc_irq() {
  // END of fill k starts fill k + 1 through PPI at once, so END and STARTED may both be pending.
  if (NRF_SAADC->EVENTS_END) {
    NRF_SAADC->EVENTS_END = 0;
    g_filled = g_filled + 1;
  }
  if (NRF_SAADC->EVENTS_STARTED) {
    NRF_SAADC->EVENTS_STARTED = 0;
    // The SAADC latched RESULT.PTR for fill g_started; point it at the buffer of the fill after.
    const uint32_t next = g_started + 1;
    NRF_SAADC->RESULT.PTR = reinterpret_cast<uint32_t>(g_dma[next % kDmaBuffers]);
    g_started = next;
  }
}

void timer_rate(uint32_t fs_hz) {
  NRF_TIMER4->TASKS_STOP = 1;
  NRF_TIMER4->TASKS_CLEAR = 1;
  NRF_TIMER4->CC[0] = kTimerHz / fs_hz;
  NRF_TIMER4->TASKS_START = 1;
}

void saadc_channels() {
  NRF_SAADC->RESOLUTION = SAADC_RESOLUTION_VAL_12bit << SAADC_RESOLUTION_VAL_Pos;
  NRF_SAADC->OVERSAMPLE = SAADC_OVERSAMPLE_OVERSAMPLE_Bypass << SAADC_OVERSAMPLE_OVERSAMPLE_Pos;
  NRF_SAADC->SAMPLERATE = SAADC_SAMPLERATE_MODE_Task << SAADC_SAMPLERATE_MODE_Pos;
  for (int c = 0; c < 8; ++c) {
    NRF_SAADC->CH[c].PSELP = SAADC_CH_PSELP_PSELP_NC;
    NRF_SAADC->CH[c].PSELN = SAADC_CH_PSELN_PSELN_NC;
  }
  for (int c = 0; c < 4; ++c) {
    // Single-ended, gain 1/4 of VDD/4: full scale = VDD (the disc's bias sits at VDD/2 = 2048 counts).
    NRF_SAADC->CH[c].CONFIG = (SAADC_CH_CONFIG_RESP_Bypass << SAADC_CH_CONFIG_RESP_Pos) |
                              (SAADC_CH_CONFIG_RESN_Bypass << SAADC_CH_CONFIG_RESN_Pos) |
                              (SAADC_CH_CONFIG_GAIN_Gain1_4 << SAADC_CH_CONFIG_GAIN_Pos) |
                              (SAADC_CH_CONFIG_REFSEL_VDD1_4 << SAADC_CH_CONFIG_REFSEL_Pos) |
                              (SAADC_CH_CONFIG_TACQ_3us << SAADC_CH_CONFIG_TACQ_Pos) |
                              (SAADC_CH_CONFIG_MODE_SE << SAADC_CH_CONFIG_MODE_Pos) |
                              (SAADC_CH_CONFIG_BURST_Disabled << SAADC_CH_CONFIG_BURST_Pos);
    NRF_SAADC->CH[c].PSELP = kPsel[c] << SAADC_CH_PSELP_PSELP_Pos;  // enabling PSELP enables the channel
  }
}

// Offset calibration with nRF52840 erratum 237 in mind (as nrfx does): the calibration may write one stray
// sample to RESULT.PTR, so it points at a scratch buffer, and the SAADC is stopped afterwards, before the
// real buffers are armed. One stray sample in a DMA buffer would rotate the channel order for the session.
void saadc_calibrate() {
  NRF_SAADC->RESULT.PTR = reinterpret_cast<uint32_t>(g_scratch);
  NRF_SAADC->RESULT.MAXCNT = 1;
  NRF_SAADC->EVENTS_CALIBRATEDONE = 0;
  NRF_SAADC->TASKS_CALIBRATEOFFSET = 1;
  while (!NRF_SAADC->EVENTS_CALIBRATEDONE) {
  }
  NRF_SAADC->EVENTS_CALIBRATEDONE = 0;
  NRF_SAADC->EVENTS_STOPPED = 0;
  NRF_SAADC->TASKS_STOP = 1;
  while (!NRF_SAADC->EVENTS_STOPPED) {
  }
  NRF_SAADC->EVENTS_STOPPED = 0;
  NRF_SAADC->EVENTS_END = 0;
  NRF_SAADC->EVENTS_STARTED = 0;
  NRF_SAADC->EVENTS_RESULTDONE = 0;
}

// Two PPI channels from the nrfx allocator (the core and the BLE stack take theirs from it too).
bool ppi_connect() {
  if (nrfx_ppi_channel_alloc(&g_ppi_sample) != NRFX_SUCCESS) return false;
  if (nrfx_ppi_channel_alloc(&g_ppi_restart) != NRFX_SUCCESS) return false;
  nrfx_ppi_channel_assign(g_ppi_sample, reinterpret_cast<uint32_t>(&NRF_TIMER4->EVENTS_COMPARE[0]),
                          reinterpret_cast<uint32_t>(&NRF_SAADC->TASKS_SAMPLE));
  nrfx_ppi_channel_assign(g_ppi_restart, reinterpret_cast<uint32_t>(&NRF_SAADC->EVENTS_END),
                          reinterpret_cast<uint32_t>(&NRF_SAADC->TASKS_START));
  nrfx_ppi_channel_enable(g_ppi_sample);
  nrfx_ppi_channel_enable(g_ppi_restart);
  return true;
}

bool acquisition_begin(uint32_t fs_hz) {
  NRF_SAADC->ENABLE = SAADC_ENABLE_ENABLE_Disabled << SAADC_ENABLE_ENABLE_Pos;
  NRF_SAADC->INTENCLR = 0xFFFFFFFFu;
  saadc_channels();
  NRF_SAADC->ENABLE = SAADC_ENABLE_ENABLE_Enabled << SAADC_ENABLE_ENABLE_Pos;
  saadc_calibrate();

  NRF_SAADC->RESULT.PTR = reinterpret_cast<uint32_t>(g_dma[0]);
  NRF_SAADC->RESULT.MAXCNT = kDmaFrames * 4;  // whole scans only, so frames never straddle buffers
  g_filled = 0;
  g_started = 0;  // the first STARTED latches buffer 0 and points RESULT.PTR at buffer 1
  NRF_SAADC->INTENSET = SAADC_INTENSET_STARTED_Msk | SAADC_INTENSET_END_Msk;
  NVIC_SetVector(SAADC_IRQn, reinterpret_cast<uint32_t>(&saadc_irq));
  NVIC_SetPriority(SAADC_IRQn, 2);
  NVIC_ClearPendingIRQ(SAADC_IRQn);
  NVIC_EnableIRQ(SAADC_IRQn);

  NRF_TIMER4->MODE = TIMER_MODE_MODE_Timer << TIMER_MODE_MODE_Pos;
  NRF_TIMER4->BITMODE = TIMER_BITMODE_BITMODE_32Bit << TIMER_BITMODE_BITMODE_Pos;
  NRF_TIMER4->PRESCALER = 0;  // 16 MHz
  NRF_TIMER4->SHORTS = TIMER_SHORTS_COMPARE0_CLEAR_Msk;
  if (!ppi_connect()) return false;

  NRF_SAADC->TASKS_START = 1;
  timer_rate(fs_hz);
  return true;
}

void cpu_begin() {
  NRF_NVMC->ICACHECNF = NVMC_ICACHECNF_CACHEEN_Enabled << NVMC_ICACHECNF_CACHEEN_Pos;  // flash wait states
  CoreDebug->DEMCR |= CoreDebug_DEMCR_TRCENA_Msk;  // DWT cycle counter for the status frame
  DWT->CYCCNT = 0;
  DWT->CTRL |= DWT_CTRL_CYCCNTENA_Msk;
}

class BoardHal : public impactapp::Hal {
 public:
  // USB CDC: never blocks. send_nb() takes what fits the endpoint's buffer when no transfer is in flight
  // (0 otherwise, or while no terminal is connected); the app keeps the rest queued (drop-and-count when
  // its queue is full). UART::availableForWrite() is Print's default 0 on this core, so it is not used.
  size_t write_some(const uint8_t* data, size_t n) override {
    uint32_t sent = 0;
    _SerialUSB.send_nb(const_cast<uint8_t*>(data), static_cast<uint32_t>(n), &sent, true);
    return sent;
  }
  void write(const uint8_t* data, size_t n) override { (void)write_some(data, n); }
  size_t writable() override { return 0; }  // write_some() decides
  void notify(const uint8_t* payload, size_t n) override {
    if (BLE.connected()) g_report.writeValue(payload, static_cast<int>(n));
  }
  bool apply_rate(uint32_t fs_hz) override {
    if (fs_hz < impactapp::kMinRateHz || fs_hz > impactapp::kMaxRateHz) return false;
    timer_rate(fs_hz);
    return true;
  }
  uint32_t cycles() override { return DWT->CYCCNT; }
  uint32_t cycles_hz() override { return kCpuHz; }
};

BoardHal g_hal;
#if IMPACTSENSE_MODELS_M2CGEN
impactapp::TableModels g_models = impactapp::exported_m2cgen_models();  // env nano33ble_m2cgen: the m2cgen C form
#else
impactapp::TableModels g_models = impactapp::exported_models();  // the node tables
#endif
impactapp::App g_app(g_hal, &g_models, impactapp::exported_config(impactapp::AppConfig()));
uint8_t g_rx[64];

// The fills completed since the last call, oldest first; fills too old to be safe are skipped as overruns.
void take_buffers() {
  uint32_t filled = g_filled;
  while (g_taken != filled) {
    const uint32_t behind = filled - g_taken;
    if (behind > kDmaBuffers - 2) {
      g_app.add_overruns(behind - (kDmaBuffers - 2));
      g_taken = filled - (kDmaBuffers - 2);
    }
    g_app.on_samples(g_dma[g_taken % kDmaBuffers], kDmaFrames);
    ++g_taken;
    filled = g_filled;
  }
}

}  // namespace

void setup() {
  cpu_begin();
  Serial.begin(115200);  // USB CDC: the baud rate is nominal; nothing waits for a terminal
  if (BLE.begin()) {
    BLE.setLocalName("impactsense");
    BLE.setAdvertisedService(g_service);
    g_service.addCharacteristic(g_report);
    g_service.addCharacteristic(g_config);
    BLE.addService(g_service);
    BLE.advertise();
  }
  if (!acquisition_begin(g_app.config().fs_hz)) {
    // No PPI channel left: nothing can be sampled. Blink the LED; the host sees no status frames.
    pinMode(LED_BUILTIN, OUTPUT);
    for (;;) {
      digitalWrite(LED_BUILTIN, !digitalRead(LED_BUILTIN));
      delay(200);
    }
  }
}

void loop() {
  take_buffers();
  // Outside acquisition only: raw dump chunks and queued frames to USB, bounded, never blocking.
  while (g_taken == g_filled && g_app.service()) {
  }
  int n = 0;
  while (n < static_cast<int>(sizeof(g_rx)) && Serial.available() > 0) g_rx[n++] = static_cast<uint8_t>(Serial.read());
  if (n > 0) g_app.on_rx(g_rx, static_cast<size_t>(n));
  BLE.poll();
  if (g_config.written()) g_app.on_rx(g_config.value(), static_cast<size_t>(g_config.valueLength()));
}
