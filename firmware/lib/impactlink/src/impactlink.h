// impactlink: the impactsense wire protocol, once, for the board and the host.
//
// Frame (all integers little-endian):
//   sync0 0xA5 | sync1 0x5A | version u8 | type u8 | len u16 | body[len] | crc32 u32
// crc32 is the IEEE/zlib CRC-32 over version, type, len and body (not the sync bytes).
// Every type has a fixed body length (raw chunks: a fixed header + a sample count that must agree), so
// a corrupted length is caught at the header. Worst-case frame: kMaxFrame bytes.
// Version: kVersion; a decoder takes frames of its own version only. A frame of another version whose CRC
// holds (its length read from its header, up to kMaxBody) is dropped whole and counted (version_errors, the
// version in other_version), never read as this version's; with a bad CRC it is a corrupt frame (crc_errors).
// Version 2 added the report's reason byte (version 1: an 18-byte report body without it).
//
// Report body (kReportBody = 19 bytes; the BLE GATT notification is [version] + this body, 20 bytes, so it
// fits the default ATT MTU of 23 (20 bytes of notification) without negotiation):
//   0  seq u32            event counter since boot (gaps = lost reports)
//   4  timestamp_ms u32   sample-clock time of the trigger frame
//   8  x i16              0.1 mm
//  10  y i16              0.1 mm
//  12  uncertainty u16    0.1 mm, 1-sigma radial, of the reported x, y: with the twin's site map its
//                         matched position's spread (twin.h spread_mm), else the TDOA localiser's
//                         covariance (0xFFFF: unknown)
//  14  energy_class u8    model class index (0 low, 1 high)
//  15  order u8           ToA order, 2 bits a place, first arrival in bits 0-1 (a permutation of 0..3)
//  16  status u8          bit0 accepted (Eq. 35), bit1 valid (features + models ran), bit2 three-channel:
//                         the models left one channel out (dead, no onset, or its energies inconsistent
//                         with the others': impactcore::twin_match), bits 3-4 that channel; other bits 0
//  17  channels u8        bits 0-3 clipped per channel, bits 4-7 dead / no onset per channel
//  18  reason u8          0 when valid; else why the models gave no position and class: an impactcore::Status
//                         code (impactcore.h IMPACTCORE_STATUS: the core's error for the capture, or the app's
//                         for a model that could not run); a valid report with a reason, or a report that is
//                         not valid without one, is malformed
//
// Status body (kStatusBody = 56 bytes), sent once a second of sample clock:
//   0  uptime_ms u32          sample-clock time
//   4  buffers u32            acquisition buffers processed since boot
//   8  overruns u32           acquisition buffers lost (the app was too late for them)
//  12  events u32             captures processed
//  16  dropped_reports u32    reports the transmit queue had no room for (the host did not read)
//  20  dropped_bytes u32      bytes of all frames dropped (reports, raw chunks, status, acks)
//  24  event_cycles_last u32  CPU cycles of the last event's processing (0: no cycle counter)
//  28  event_cycles_max u32   the most since boot
//  32  buffer_cycles_max u32  the most an acquisition buffer without an event took, over the last period
//  36  idle_load u16          permille of the buffer period those buffers took on average (0xFFFF unknown)
//  38  threshold u16          the trigger threshold in use, counts (the noise-tracked one: the largest
//                             channel's max(configured, noise_factor x its tracked noise rms))
//  40  health u8[4]           per channel, in the last event: bit0 dead (flat / no signal), bit1 clipped,
//                             bit2 no onset, bit3 a mains hum was modelled, bit4 a 1-2 sample glitch was
//                             left out, bit5 inconsistent (the models left it out for its energies);
//                             bits 6-7 reserved (0)
//  44  noise u16[4]           per channel noise RMS the trigger tracks (before it is armed: the last event's
//                             baseline noise), 0.1 counts (0xFFFF unknown)
//  52  raw_dropped u16        raw dumps cut short by the next capture
//  54  flags u8               bit0 dump raw on, bit1 cycle counter present
//  55  reserved u8            0
//
// Commands (host -> board): set threshold (u16 counts), set rate (u32 Hz per channel), dump raw
// (u8 0/1: send each capture as raw chunks before its report), get config (empty). The board answers
// each command with an ack carrying its configuration.
#pragma once

#include <stddef.h>
#include <stdint.h>

namespace impactlink {

constexpr uint8_t kSync0 = 0xA5;
constexpr uint8_t kSync1 = 0x5A;
constexpr uint8_t kVersion = 2;
constexpr size_t kHeaderBytes = 6;
constexpr size_t kCrcBytes = 4;
constexpr size_t kMaxBody = 1024;
constexpr size_t kMaxFrame = kHeaderBytes + kMaxBody + kCrcBytes;
constexpr size_t kReportBody = 19;
constexpr size_t kReportFrame = kHeaderBytes + kReportBody + kCrcBytes;  // 29 bytes
constexpr size_t kBlePayload = 1 + kReportBody;                          // 20 bytes
constexpr size_t kAckBody = 12;
constexpr size_t kStatusBody = 56;
constexpr size_t kStatusFrame = kHeaderBytes + kStatusBody + kCrcBytes;  // 66 bytes
constexpr size_t kRawHeader = 11;
constexpr size_t kMaxRawSamples = (kMaxBody - kRawHeader) / 2;  // 506 int16 per chunk

enum FrameType : uint8_t {
  kTypeReport = 0x01,
  kTypeRaw = 0x02,
  kTypeAck = 0x03,
  kTypeStatus = 0x04,
  kCmdSetThreshold = 0x10,
  kCmdSetRate = 0x11,
  kCmdDumpRaw = 0x12,
  kCmdGetConfig = 0x13,
};

enum ReportStatus : uint8_t {
  kReportAccepted = 1u << 0,
  kReportValid = 1u << 1,
  kReportLeftOut = 1u << 2,  // bits 3-4: the channel
};
constexpr int kReportLeftOutShift = 3;

struct Report {
  uint32_t seq;
  uint32_t timestamp_ms;
  float x_mm, y_mm;
  float uncertainty_mm;   // negative or NaN: unknown
  uint8_t energy_class;
  uint8_t order[4];
  bool accepted;
  bool valid;
  uint8_t clipped;        // bit c: channel c clipped
  uint8_t dead;           // bit c: channel c dead or without onset
  int8_t left_out = -1;   // the channel the models left out (-1: none)
  uint8_t reason = 0;     // not valid: why (an impactcore::Status code); valid: 0
};

// One capture chunk: `count` samples of one channel starting at `offset` of a `total`-sample capture.
struct RawChunk {
  uint32_t event_seq;
  uint8_t channel;
  uint16_t total;
  uint16_t offset;
  uint16_t count;
  const uint8_t* samples_le;  // count int16 LE (points into the frame body)
};

struct Ack {
  uint8_t command;   // the command type answered
  uint8_t status;    // 0 ok, 1 value rejected, 2 unknown command
  uint32_t fs_hz;
  uint16_t threshold_counts;
  uint16_t capture_frames;
  uint8_t dump_raw;
};

// Once a second: the board's health (see the body layout above).
struct Status {
  uint32_t uptime_ms;
  uint32_t buffers;
  uint32_t overruns;
  uint32_t events;
  uint32_t dropped_reports;
  uint32_t dropped_bytes;
  uint32_t event_cycles_last;
  uint32_t event_cycles_max;
  uint32_t buffer_cycles_max;
  uint16_t idle_load_permille;  // 0xFFFF: unknown (no cycle counter)
  uint16_t threshold_counts;
  uint8_t health[4];
  uint16_t noise_x10[4];        // 0xFFFF: unknown
  uint16_t raw_dropped;
  uint8_t flags;
};
enum StatusFlags : uint8_t { kStatusDumpRaw = 1u << 0, kStatusCycleCounter = 1u << 1 };
enum ChannelHealth : uint8_t {
  kHealthDead = 1u << 0,
  kHealthClipped = 1u << 1,
  kHealthNoOnset = 1u << 2,
  kHealthHum = 1u << 3,
  kHealthGlitch = 1u << 4,
  kHealthInconsistent = 1u << 5,
};

// --- CRC and bodies ---
uint32_t crc32(const uint8_t* data, size_t n, uint32_t crc = 0);
void pack_report(const Report& r, uint8_t body[kReportBody]);
bool unpack_report(const uint8_t* body, size_t len, Report* r);  // false: not a well-formed report
void pack_ack(const Ack& a, uint8_t body[kAckBody]);
bool unpack_ack(const uint8_t* body, size_t len, Ack* a);
bool unpack_raw(const uint8_t* body, size_t len, RawChunk* c);
void pack_status(const Status& s, uint8_t body[kStatusBody]);
bool unpack_status(const uint8_t* body, size_t len, Status* s);

// Body length a type must have; for raw chunks the minimum (kRawHeader). -1: unknown type.
int expected_body_length(uint8_t type);
bool body_length_ok(uint8_t type, size_t len, const uint8_t* body_head /* >= kRawHeader bytes or null */);

// --- encoding: returns the frame length written to out, 0 if it does not fit ---
size_t encode_frame(uint8_t type, const uint8_t* body, size_t len, uint8_t* out, size_t cap);
size_t encode_report(const Report& r, uint8_t* out, size_t cap);
size_t encode_ack(const Ack& a, uint8_t* out, size_t cap);
size_t encode_status(const Status& s, uint8_t* out, size_t cap);
size_t encode_raw(uint32_t event_seq, uint8_t channel, uint16_t total, uint16_t offset,
                  const int16_t* samples, uint16_t count, uint8_t* out, size_t cap);
size_t encode_command(uint8_t type, uint32_t value, uint8_t* out, size_t cap);

// BLE: [version] + report body.
size_t ble_payload(const Report& r, uint8_t out[kBlePayload]);
bool parse_ble_payload(const uint8_t* p, size_t n, Report* r);

// --- streaming decoder: one byte at a time, never allocates ---
struct Frame {
  uint8_t version;
  uint8_t type;
  uint16_t len;
  uint8_t body[kMaxBody];
};

struct DecoderStats {
  uint32_t frames;          // well-formed frames emitted
  uint32_t crc_errors;
  uint32_t length_errors;   // length not allowed for the type
  uint32_t version_errors;  // whole frames (CRC right) of another protocol version, dropped
  uint32_t type_errors;     // unknown frame type
  uint32_t payload_errors;  // CRC fine but a report body is malformed (never emitted)
  uint32_t bytes_skipped;   // bytes dropped while hunting for a frame start
  uint8_t other_version;    // the version of the last such frame (0: none yet)
};

class Decoder {
 public:
  // Feeds one byte; true when a frame completed (copied into *out). After a true, call poll() until it
  // returns false: bytes kept after a rejected frame may already hold further frames.
  bool push(uint8_t byte, Frame* out);
  bool poll(Frame* out);
  void reset();
  const DecoderStats& stats() const { return stats_; }
  uint32_t errors() const {
    return stats_.crc_errors + stats_.length_errors + stats_.version_errors + stats_.type_errors +
           stats_.payload_errors;
  }

 private:
  void drop(size_t n);  // discard the first n buffered bytes
  uint8_t buf_[kMaxFrame];
  size_t n_ = 0;
  DecoderStats stats_ = {};
};

}  // namespace impactlink
