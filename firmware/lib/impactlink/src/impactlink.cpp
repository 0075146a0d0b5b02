// impactlink codec: framing, CRC, bodies and the resynchronising stream decoder.
#include "impactlink.h"

#include <math.h>
#include <string.h>

namespace impactlink {
namespace {

// CRC-32 (IEEE 802.3, reflected 0xEDB88320, as zlib) with a 16-entry nibble table: 64 bytes of flash.
const uint32_t kCrcNibble[16] = {
    0x00000000u, 0x1DB71064u, 0x3B6E20C8u, 0x26D930ACu, 0x76DC4190u, 0x6B6B51F4u,
    0x4DB26158u, 0x5005713Cu, 0xEDB88320u, 0xF00F9344u, 0xD6D6A3E8u, 0xCB61B38Cu,
    0x9B64C2B0u, 0x86D3D2D4u, 0xA00AE278u, 0xBDBDF21Cu};

void put16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
}
void put32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
uint16_t get16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }
uint32_t get32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
         (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24);
}

// mm (float) -> 0.1 mm int16, saturated; NaN -> 0.
int16_t tenth_mm(float v) {
  if (!(v == v)) return 0;
  float t = v * 10.0f;
  t = t >= 0.0f ? t + 0.5f : t - 0.5f;
  if (t > 32767.0f) return 32767;
  if (t < -32768.0f) return -32768;
  return static_cast<int16_t>(t);
}

}  // namespace

uint32_t crc32(const uint8_t* data, size_t n, uint32_t crc) {
  crc = ~crc;
  for (size_t i = 0; i < n; ++i) {
    crc ^= data[i];
    crc = (crc >> 4) ^ kCrcNibble[crc & 0x0Fu];
    crc = (crc >> 4) ^ kCrcNibble[crc & 0x0Fu];
  }
  return ~crc;
}

void pack_report(const Report& r, uint8_t b[kReportBody]) {
  put32(b + 0, r.seq);
  put32(b + 4, r.timestamp_ms);
  put16(b + 8, static_cast<uint16_t>(tenth_mm(r.x_mm)));
  put16(b + 10, static_cast<uint16_t>(tenth_mm(r.y_mm)));
  uint16_t u = 0xFFFFu;
  if (r.uncertainty_mm >= 0.0f) {
    const float t = r.uncertainty_mm * 10.0f + 0.5f;
    u = t >= 65534.0f ? 65534u : static_cast<uint16_t>(t);
  }
  put16(b + 12, u);
  b[14] = r.energy_class;
  uint8_t order = 0;
  for (int i = 0; i < 4; ++i) order |= static_cast<uint8_t>((r.order[i] & 3u) << (2 * i));
  b[15] = order;
  b[16] = static_cast<uint8_t>((r.accepted ? kReportAccepted : 0) | (r.valid ? kReportValid : 0));
  if (r.left_out >= 0 && r.left_out < 4) {
    b[16] = static_cast<uint8_t>(b[16] | kReportLeftOut | (r.left_out << kReportLeftOutShift));
  }
  b[17] = static_cast<uint8_t>((r.clipped & 0x0Fu) | ((r.dead & 0x0Fu) << 4));
  b[18] = r.reason;
}

bool unpack_report(const uint8_t* b, size_t len, Report* r) {
  if (b == nullptr || len != kReportBody) return false;
  if (b[16] & ~(kReportAccepted | kReportValid | kReportLeftOut | (3u << kReportLeftOutShift))) {
    return false;  // reserved status bits
  }
  if (!(b[16] & kReportLeftOut) && (b[16] >> kReportLeftOutShift) & 3u) return false;  // a channel, none left out
  uint8_t seen = 0;
  uint8_t order[4];
  for (int i = 0; i < 4; ++i) {
    order[i] = (b[15] >> (2 * i)) & 3u;
    seen |= static_cast<uint8_t>(1u << order[i]);
  }
  if (seen != 0x0Fu) return false;  // the ToA order must be a permutation
  if (b[14] > 15) return false;     // energy classes are small indices
  if (((b[16] & kReportValid) != 0) == (b[18] != 0)) return false;  // a reason exactly when not valid
  r->seq = get32(b);
  r->timestamp_ms = get32(b + 4);
  r->x_mm = static_cast<float>(static_cast<int16_t>(get16(b + 8))) * 0.1f;
  r->y_mm = static_cast<float>(static_cast<int16_t>(get16(b + 10))) * 0.1f;
  const uint16_t u = get16(b + 12);
  r->uncertainty_mm = u == 0xFFFFu ? -1.0f : static_cast<float>(u) * 0.1f;
  r->energy_class = b[14];
  memcpy(r->order, order, 4);
  r->accepted = (b[16] & kReportAccepted) != 0;
  r->valid = (b[16] & kReportValid) != 0;
  r->clipped = b[17] & 0x0Fu;
  r->dead = b[17] >> 4;
  r->left_out = (b[16] & kReportLeftOut) ? static_cast<int8_t>((b[16] >> kReportLeftOutShift) & 3u) : -1;
  r->reason = b[18];
  return true;
}

void pack_ack(const Ack& a, uint8_t b[kAckBody]) {
  b[0] = a.command;
  b[1] = a.status;
  put32(b + 2, a.fs_hz);
  put16(b + 6, a.threshold_counts);
  put16(b + 8, a.capture_frames);
  b[10] = a.dump_raw;
  b[11] = 0;
}

bool unpack_ack(const uint8_t* b, size_t len, Ack* a) {
  if (b == nullptr || len != kAckBody) return false;
  a->command = b[0];
  a->status = b[1];
  a->fs_hz = get32(b + 2);
  a->threshold_counts = get16(b + 6);
  a->capture_frames = get16(b + 8);
  a->dump_raw = b[10];
  return true;
}

void pack_status(const Status& s, uint8_t* b) {
  const uint32_t u32[9] = {s.uptime_ms, s.buffers, s.overruns, s.events, s.dropped_reports,
                           s.dropped_bytes, s.event_cycles_last, s.event_cycles_max, s.buffer_cycles_max};
  for (int i = 0; i < 9; ++i) put32(b + 4 * i, u32[i]);
  put16(b + 36, s.idle_load_permille);
  put16(b + 38, s.threshold_counts);
  for (int c = 0; c < 4; ++c) {
    b[40 + c] = s.health[c];
    put16(b + 44 + 2 * c, s.noise_x10[c]);
  }
  put16(b + 52, s.raw_dropped);
  b[54] = s.flags;
  b[55] = 0;
}

bool unpack_status(const uint8_t* b, size_t len, Status* s) {
  if (b == nullptr || len != kStatusBody) return false;
  uint32_t* u32[9] = {&s->uptime_ms, &s->buffers, &s->overruns, &s->events, &s->dropped_reports,
                      &s->dropped_bytes, &s->event_cycles_last, &s->event_cycles_max, &s->buffer_cycles_max};
  for (int i = 0; i < 9; ++i) *u32[i] = get32(b + 4 * i);
  s->idle_load_permille = get16(b + 36);
  s->threshold_counts = get16(b + 38);
  for (int c = 0; c < 4; ++c) {
    s->health[c] = b[40 + c];
    s->noise_x10[c] = get16(b + 44 + 2 * c);
  }
  s->raw_dropped = get16(b + 52);
  s->flags = b[54];
  return true;
}

bool unpack_raw(const uint8_t* b, size_t len, RawChunk* c) {
  if (!body_length_ok(kTypeRaw, len, b)) return false;
  c->event_seq = get32(b);
  c->channel = b[4];
  c->total = get16(b + 5);
  c->offset = get16(b + 7);
  c->count = get16(b + 9);
  c->samples_le = b + kRawHeader;
  return true;
}

int expected_body_length(uint8_t type) {
  switch (type) {
    case kTypeReport: return static_cast<int>(kReportBody);
    case kTypeRaw: return static_cast<int>(kRawHeader);
    case kTypeAck: return static_cast<int>(kAckBody);
    case kTypeStatus: return static_cast<int>(kStatusBody);
    case kCmdSetThreshold: return 2;
    case kCmdSetRate: return 4;
    case kCmdDumpRaw: return 1;
    case kCmdGetConfig: return 0;
    default: return -1;
  }
}

bool body_length_ok(uint8_t type, size_t len, const uint8_t* head) {
  const int want = expected_body_length(type);
  if (want < 0) return false;
  if (type != kTypeRaw) return len == static_cast<size_t>(want);
  if (len < kRawHeader + 2 || len > kMaxBody || ((len - kRawHeader) & 1u)) return false;
  if (head == nullptr) return true;  // the chunk header is checked once it has arrived
  const uint16_t total = get16(head + 5), offset = get16(head + 7), count = get16(head + 9);
  return head[4] < 4 && count == (len - kRawHeader) / 2 &&
         static_cast<uint32_t>(offset) + count <= total;
}

size_t encode_frame(uint8_t type, const uint8_t* body, size_t len, uint8_t* out, size_t cap) {
  if (len > kMaxBody || cap < kHeaderBytes + len + kCrcBytes) return 0;
  out[0] = kSync0;
  out[1] = kSync1;
  out[2] = kVersion;
  out[3] = type;
  put16(out + 4, static_cast<uint16_t>(len));
  if (len) memcpy(out + kHeaderBytes, body, len);
  put32(out + kHeaderBytes + len, crc32(out + 2, kHeaderBytes - 2 + len));
  return kHeaderBytes + len + kCrcBytes;
}

size_t encode_report(const Report& r, uint8_t* out, size_t cap) {
  uint8_t body[kReportBody];
  pack_report(r, body);
  return encode_frame(kTypeReport, body, kReportBody, out, cap);
}

size_t encode_ack(const Ack& a, uint8_t* out, size_t cap) {
  uint8_t body[kAckBody];
  pack_ack(a, body);
  return encode_frame(kTypeAck, body, kAckBody, out, cap);
}

size_t encode_status(const Status& s, uint8_t* out, size_t cap) {
  uint8_t body[kStatusBody];
  pack_status(s, body);
  return encode_frame(kTypeStatus, body, kStatusBody, out, cap);
}

size_t encode_raw(uint32_t event_seq, uint8_t channel, uint16_t total, uint16_t offset,
                  const int16_t* samples, uint16_t count, uint8_t* out, size_t cap) {
  const size_t len = kRawHeader + 2u * count;
  if (count == 0 || count > kMaxRawSamples || cap < kHeaderBytes + len + kCrcBytes) return 0;
  // Build the body in place to avoid a second 1 KB buffer.
  uint8_t* b = out + kHeaderBytes;
  put32(b, event_seq);
  b[4] = channel;
  put16(b + 5, total);
  put16(b + 7, offset);
  put16(b + 9, count);
  for (uint16_t i = 0; i < count; ++i) put16(b + kRawHeader + 2 * i, static_cast<uint16_t>(samples[i]));
  out[0] = kSync0;
  out[1] = kSync1;
  out[2] = kVersion;
  out[3] = kTypeRaw;
  put16(out + 4, static_cast<uint16_t>(len));
  put32(out + kHeaderBytes + len, crc32(out + 2, kHeaderBytes - 2 + len));
  return kHeaderBytes + len + kCrcBytes;
}

size_t encode_command(uint8_t type, uint32_t value, uint8_t* out, size_t cap) {
  uint8_t body[4];
  const int len = expected_body_length(type);
  if (type < kCmdSetThreshold || len < 0) return 0;
  put32(body, value);
  if (len == 2 && value > 0xFFFFu) return 0;
  if (len == 1 && value > 0xFFu) return 0;
  return encode_frame(type, body, static_cast<size_t>(len), out, cap);
}

size_t ble_payload(const Report& r, uint8_t out[kBlePayload]) {
  out[0] = kVersion;
  pack_report(r, out + 1);
  return kBlePayload;
}

bool parse_ble_payload(const uint8_t* p, size_t n, Report* r) {
  if (p == nullptr || n != kBlePayload || p[0] != kVersion) return false;
  return unpack_report(p + 1, n - 1, r);
}

// --- decoder ---

void Decoder::reset() {
  n_ = 0;
  stats_ = DecoderStats{};
}

void Decoder::drop(size_t k) {
  if (k >= n_) {
    n_ = 0;
    return;
  }
  memmove(buf_, buf_ + k, n_ - k);
  n_ -= k;
}

bool Decoder::push(uint8_t byte, Frame* out) {
  if (n_ == sizeof(buf_)) {  // only if poll() was not called after a true; keep going
    drop(1);
    ++stats_.bytes_skipped;
  }
  buf_[n_++] = byte;
  return poll(out);
}

bool Decoder::poll(Frame* out) {
  for (;;) {
    if (n_ == 0) return false;
    if (buf_[0] != kSync0) {
      drop(1);
      ++stats_.bytes_skipped;
      continue;
    }
    if (n_ < 2) return false;
    if (buf_[1] != kSync1) {
      drop(1);
      ++stats_.bytes_skipped;
      continue;
    }
    if (n_ < 3) return false;
    if (buf_[2] != kVersion) {
      // Another version's frame: its layout is unknown, but its header's length and CRC are the same. Dropped
      // whole and counted when its CRC holds; otherwise a corrupt frame, resynchronised from the next byte.
      if (n_ < kHeaderBytes) return false;
      const size_t len = get16(buf_ + 4);
      const size_t total = kHeaderBytes + len + kCrcBytes;
      if (len <= kMaxBody && n_ < total) return false;
      if (len <= kMaxBody && crc32(buf_ + 2, kHeaderBytes - 2 + len) == get32(buf_ + kHeaderBytes + len)) {
        ++stats_.version_errors;
        stats_.other_version = buf_[2];
        drop(total);
      } else {
        ++(len <= kMaxBody ? stats_.crc_errors : stats_.length_errors);
        drop(1);
      }
      continue;
    }
    if (n_ < 4) return false;
    const uint8_t type = buf_[3];
    if (expected_body_length(type) < 0) {
      ++stats_.type_errors;
      drop(1);
      continue;
    }
    if (n_ < kHeaderBytes) return false;
    const size_t len = get16(buf_ + 4);
    if (!body_length_ok(type, len, nullptr)) {
      ++stats_.length_errors;
      drop(1);
      continue;
    }
    if (type == kTypeRaw && n_ >= kHeaderBytes + kRawHeader &&
        !body_length_ok(type, len, buf_ + kHeaderBytes)) {
      ++stats_.length_errors;
      drop(1);
      continue;
    }
    const size_t total = kHeaderBytes + len + kCrcBytes;
    if (n_ < total) return false;
    if (crc32(buf_ + 2, kHeaderBytes - 2 + len) != get32(buf_ + kHeaderBytes + len)) {
      ++stats_.crc_errors;
      drop(1);
      continue;
    }
    if (type == kTypeReport) {
      Report r;
      if (!unpack_report(buf_ + kHeaderBytes, len, &r)) {
        ++stats_.payload_errors;
        drop(total);
        continue;
      }
    }
    out->version = buf_[2];
    out->type = type;
    out->len = static_cast<uint16_t>(len);
    memcpy(out->body, buf_ + kHeaderBytes, len);
    drop(total);
    ++stats_.frames;
    return true;
  }
}

}  // namespace impactlink
