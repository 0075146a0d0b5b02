// ASan/UBSan driver: the portable firmware (core + app + codec) over recordings, built with
// -fsanitize=address,undefined. Reads int16 frames [R][n][4] (board rate) from argv[1], with R and n in
// argv[2], argv[3]; runs the App (with the exported table models) over the whole stream, the core directly
// on each capture, and the decoder over the produced bytes plus corrupted copies. Prints "reports N".
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <vector>

#include "impactapp.h"
#include "impactapp_models.h"

struct Hal : impactapp::Hal {
  std::vector<uint8_t> out;
  void write(const uint8_t* d, size_t n) override { out.insert(out.end(), d, d + n); }
};

int main(int argc, char** argv) {
  if (argc < 4) return 2;
  const long r = atol(argv[2]), n = atol(argv[3]);
  std::vector<int16_t> frames(static_cast<size_t>(r * n * 4));
  FILE* f = fopen(argv[1], "rb");
  if (!f || fread(frames.data(), 2, frames.size(), f) != frames.size()) return 3;
  fclose(f);
  static Hal hal;
  static impactapp::TableModels models = impactapp::exported_models();
  static impactapp::AppConfig cfg = impactapp::exported_config(impactapp::AppConfig());
  cfg.dump_raw = true;
  static impactapp::App app(hal, &models, cfg);
  for (long k = 0; k < r; ++k) {
    for (long off = 0; off < n; off += 256) {
      const long m = n - off < 256 ? n - off : 256;
      app.on_samples(frames.data() + (k * n + off) * 4, static_cast<int>(m));
      while (app.service()) {  // the board's loop(): raw chunks and queued frames out between buffers
      }
    }
  }
  // decode everything, then a corrupted copy
  static impactlink::Decoder dec;
  static impactlink::Frame fr;
  long reports = 0, valid = 0;
  for (uint8_t b : hal.out) {
    if (!dec.push(b, &fr)) continue;
    do {
      impactlink::Report rep;
      if (fr.type != impactlink::kTypeReport) continue;
      ++reports;
      if (impactlink::unpack_report(fr.body, fr.len, &rep) && rep.valid) ++valid;  // the models ran
    } while (dec.poll(&fr));
  }
  std::vector<uint8_t> bad(hal.out);
  srand(1);
  for (size_t i = 0; i < bad.size(); i += 1 + rand() % 97) bad[i] ^= static_cast<uint8_t>(1 + rand() % 255);
  dec.reset();
  for (uint8_t b : bad) {
    if (!dec.push(b, &fr)) continue;
    while (dec.poll(&fr)) {
    }
  }
  // core edge cases: short, flat and clipped captures
  static int16_t flat[4][300];
  for (int c = 0; c < 4; ++c) for (int i = 0; i < 300; ++i) flat[c][i] = static_cast<int16_t>(c == 1 ? (i % 2) * 4095 : 2048);
  const int16_t* ch[4] = {flat[0], flat[1], flat[2], flat[3]};
  static impactcore::EventResult ev;
  impactcore::process_event(ch, 300, cfg.core, cfg.loc, &ev);
  impactcore::process_event(ch, 10, cfg.core, cfg.loc, &ev);
  uint8_t cls;
  float x, y;
  models.predict(ev, &x, &y, &cls);
  printf("reports %ld events %u decode_errors %u valid %ld twin %d\n", reports, app.events(), dec.errors(), valid,
         models.has_twin() ? 1 : 0);
  return reports == static_cast<long>(app.events()) ? 0 : 1;
}
