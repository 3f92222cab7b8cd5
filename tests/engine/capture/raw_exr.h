#pragma once
// WriteRawExr: writes a float OpenEXR file exactly as given — NaN and Inf included — for tests of
// readers that must reject such values. engine/image's WriteExr cannot: it sanitises every value
// it writes (no NaN or Inf reaches a file written by reflcap), which is what a bad file from
// another program does not do. Channels named as WriteExr names them (1: Y, 3: R,G,B).
#include <filesystem>
#include <string>
#include <vector>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>

#include "engine/image/image.h"

namespace reflcap::testing {

inline void WriteRawExr(const std::filesystem::path& path, const Image& image) {
  const std::vector<std::string> names =
      image.channels == 1 ? std::vector<std::string>{"Y"} : std::vector<std::string>{"R", "G", "B"};
  Imf::Header header(image.width, image.height);
  for (const std::string& name : names) header.channels().insert(name, Imf::Channel(Imf::FLOAT));
  Imf::FrameBuffer frame;
  const size_t pixel = sizeof(float) * size_t(image.channels);
  for (size_t c = 0; c < names.size(); ++c) {
    frame.insert(names[c], Imf::Slice(Imf::FLOAT, (char*)(image.data.data() + c), pixel,
                                      pixel * size_t(image.width)));
  }
  Imf::OutputFile file(path.c_str(), header);
  file.setFrameBuffer(frame);
  file.writePixels(image.height);
}

}  // namespace reflcap::testing
