// The bad-input corpus (README.md, "Hardening"): malformed files and flags for every verb of the
// `reflcap` executable, each run as a new user would run it. Every case asserts
//   - the exit code (1 usage, 2 bad input, 4 internal: cli/cli.h),
//   - that stderr names the file (or flag) and the field at fault,
//   - that nothing was left behind: the output does not exist (or is still empty) and no new
//     file or folder appeared anywhere in the case's working folder (no staging leftovers);
//     the few inputs a verb accepts with a warning (a params.exr holding NaN renders those
//     texels black) assert exit 0 and the warning instead.
// Cases cover NaN/Inf in JSON (1e999 parses to infinity) and in EXR, 0-byte and enormous images,
// wrong channel counts, degenerate meshes, UVs outside [0,1], duplicate ids, paths with spaces
// and non-ASCII characters, a read-only output folder and a full disk (`ulimit -f`).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;
using testing::CliResult;
using testing::ScratchDir;

// Exit codes of cli/cli.h.
constexpr int kUsage = 1;
constexpr int kBadInput = 2;
constexpr int kInternal = 4;

// The argument quoted for /bin/sh (paths with spaces, quotes and non-ASCII characters).
std::string Q(const fs::path& path) { return testing::ShellQuote(path.string()); }

// Runs `reflcap ARGS` through the shell, with `prefix` (shell commands such as a ulimit) first;
// stdout and stderr go to files in `logs`.
CliResult RunCli(const std::string& args, const ScratchDir& logs, const std::string& prefix = "") {
  const fs::path out = logs / "stdout.txt", err = logs / "stderr.txt";
  const std::string command = prefix + std::string(REFLCAP_BINARY) + " " + args + " >" +
                              Q(out) + " 2>" + Q(err);
  const int status = std::system(command.c_str());
  CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadTextFile(out).value();
  r.err = ReadTextFile(err).value();
  return r;
}

// Every path under `dir` (recursively), relative to it.
std::set<std::string> Listing(const fs::path& dir) {
  std::set<std::string> paths;
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    paths.insert(fs::relative(it->path(), dir).string());
  }
  return paths;
}

// One corpus case: `prepare` builds its inputs in `work` and returns the arguments; the command
// must exit with `exit_code`, and stderr must contain every string of `mentions`.
struct Case {
  Case(std::string what_, std::function<std::string(const fs::path& work)> prepare_, int exit_code_,
       std::vector<std::string> mentions_, std::string prefix_ = "")
      : what(std::move(what_)), prepare(std::move(prepare_)), exit_code(exit_code_),
        mentions(std::move(mentions_)), prefix(std::move(prefix_)) {}
  std::string what;
  std::function<std::string(const fs::path& work)> prepare;
  int exit_code;
  std::vector<std::string> mentions;
  std::string prefix;  // shell commands run before reflcap (ulimit)
};

void ExpectRefused(const Case& c) {
  SCOPED_TRACE(c.what);
  ScratchDir work, logs;
  const std::string args = c.prepare(work.path());
  const std::set<std::string> before = Listing(work.path());
  const CliResult r = RunCli(args, logs, c.prefix);
  EXPECT_EQ(r.exit_code, c.exit_code) << "reflcap " << args << "\n" << r.err;
  for (const std::string& m : c.mentions) {
    EXPECT_NE(r.err.find(m), std::string::npos) << "expected \"" << m << "\" in: " << r.err;
  }
  // Cases that must succeed (with a warning) do write their output.
  if (c.exit_code == 0) return;
  // Nothing new: no output, no staging folder, no temporary file (output folders that existed
  // empty before still exist, empty).
  const std::set<std::string> after = Listing(work.path());
  std::vector<std::string> left;
  for (const std::string& p : after) {
    if (!before.count(p)) left.push_back(p);
  }
  EXPECT_TRUE(left.empty()) << left.size() << " paths left behind, the first: " << left.front();
}

void RunCases(const std::vector<Case>& cases) {
  for (const Case& c : cases) ExpectRefused(c);
}

// ---- Fixtures (made once per test process by the reflcap binary itself) ----------------------

const fs::path& Fixtures() {
  static const ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  return dir->path();
}

void MakeOnce(const fs::path& out, const std::string& args) {
  if (fs::exists(out)) return;
  ScratchDir logs;
  const CliResult r = RunCli(args, logs);
  REFLCAP_CHECK(r.exit_code == 0) << args << "\n" << r.err;
}

// A tiny synthetic capture (mesh, 2 cameras, 2 lights, 4 steps; 48 px photographs).
fs::path TinyCapture() {
  const fs::path out = Fixtures() / "capture";
  MakeOnce(out, "synth --quiet --out " + Q(out) +
                    " --texels 2000 --image-size 48 --cameras 2 --lights 2 --steps 4");
  return out;
}
fs::path TinySamples() {
  const fs::path out = Fixtures() / "samples";
  MakeOnce(out, "resample --quiet " + Q(TinyCapture()) + " --out " + Q(out) + " --atlas-res 64");
  return out;
}
fs::path TinyFit() {
  const fs::path out = Fixtures() / "fit";
  MakeOnce(out, "fit --quiet " + Q(TinySamples()) + " --out " + Q(out) + " --backend cpu");
  return out;
}
fs::path TinyRenders() {
  const fs::path out = Fixtures() / "renders";
  MakeOnce(out, "render --quiet " + Q(TinyCapture()) + " " + Q(TinyFit()) + " --out " + Q(out) +
                    " --split holdout --backend cpu");
  return out;
}

fs::path TinyResamplePart(int index) {
  const fs::path out = Fixtures() / ("resample_part" + std::to_string(index));
  MakeOnce(out, "resample --quiet " + Q(TinyCapture()) + " --out " + Q(out) + " --atlas-res 64 --shard " +
                    std::to_string(index) + "/2");
  return out;
}

// Copies `from` to work/name and returns the copy.
fs::path CopyTo(const fs::path& from, const fs::path& work, const std::string& name) {
  const fs::path to = work / name;
  fs::create_directories(to.parent_path());
  fs::copy(from, to, fs::copy_options::recursive);
  return to;
}

Json ReadJson(const fs::path& path) { return Json::parse(ReadTextFile(path).value()); }
void WriteJson(const fs::path& path, const Json& json) { testing::WriteText(path, json.dump(1)); }

// Copies the tiny capture into work/capture, applies `edit` to its capture.json, returns the
// capture.json path.
fs::path EditedCapture(const fs::path& work, const std::function<void(Json&, const fs::path&)>& edit,
                       const std::string& name = "capture") {
  const fs::path dir = CopyTo(TinyCapture(), work, name);
  Json json = ReadJson(dir / "capture.json");
  edit(json, dir);
  WriteJson(dir / "capture.json", json);
  return dir / "capture.json";
}

// Replaces the first occurrence of `from` in the file with `to` (JSON edits nlohmann cannot
// express: NaN literals, numbers that overflow a double).
void ReplaceInFile(const fs::path& path, const std::string& from, const std::string& to) {
  std::string text = ReadTextFile(path).value();
  const size_t at = text.find(from);
  REFLCAP_CHECK(at != std::string::npos) << from << " not in " << path;
  text.replace(at, from.size(), to);
  testing::WriteText(path, text);
}

void WriteBytes(const fs::path& path, const std::string& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << bytes;
}

// RGB channels of one value everywhere.
std::map<std::string, std::vector<float>> Rgb(int width, int height, float value) {
  const std::vector<float> plane(size_t(width) * height, value);
  return {{"R", plane}, {"G", plane}, {"B", plane}};
}

bool RunningAsRoot() { return ::geteuid() == 0; }

// ---- info: capture.json and the files it names ------------------------------------------------

TEST(BadInputCorpus, Info) {
  const std::vector<Case> cases = {
      {"exposure that overflows a double (1e999 = inf)",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["images"][0]["exposure_s"] = 123.25;
         });
         ReplaceInFile(json, "123.25", "1e999");
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "images[0].exposure_s"}},
      {"camera matrix entry -1e999 (-inf)",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["cameras"][1]["K"][0][2] = 123.25;
         });
         ReplaceInFile(json, "123.25", "-1e999");
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "cameras[1].K"}},
      {"NaN literal in JSON",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["lights"][0]["intensity"][1] = 123.25;
         });
         ReplaceInFile(json, "123.25", "NaN");
         return "info " + Q(json);
       },
       kBadInput, {"capture.json:", "JSON syntax error"}},
      {"light intensity inf",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["lights"][1]["intensity"][2] = 123.25;
         });
         ReplaceInFile(json, "123.25", "1e400");
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "lights[1].intensity"}},
      {"turntable angle inf",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["images"][2]["turntable_deg"] = 123.25;
         });
         ReplaceInFile(json, "123.25", "1e999");
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "images[2].turntable_deg"}},
      {"0-byte photograph",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           fs::resize_file(d / j["images"][1]["file"].get<std::string>(), 0);
         });
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "images[1].file"}},
      {"enormous photograph (200000 x 200000 header)",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           WriteBytes(d / j["images"][0]["file"].get<std::string>(),
                      testing::RawExr(200000, 200000, Rgb(1, 1, 0), /*header_only=*/true));
         });
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "images[0].file", "0000.exr"}},
      {"camera height 0",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) { j["cameras"][1]["height"] = 0; });
         return "info " + Q(json);
       },
       kBadInput, {"capture.json", "cameras[1].height"}},
      {"mesh of degenerate triangles only",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           testing::WriteText(d / j["mesh"].get<std::string>(),
                              "v 0 0 0\nv 1 0 0\nv 2 0 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                              "f 1/1 2/2 3/3\nf 1/1 1/2 2/3\n");
         });
         return "info " + Q(json);
       },
       kBadInput, {"mesh.obj", "triangle"}},
      {"mesh with NaN vertices only",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           testing::WriteText(d / j["mesh"].get<std::string>(),
                              "v nan 0 0\nv 1 nan 0\nv 0 1 inf\nvt 0 0\nvt 1 0\nvt 0 1\n"
                              "f 1/1 2/2 3/3\n");
         });
         return "info " + Q(json);
       },
       kBadInput, {"mesh.obj", "triangle"}},
      {"mesh face index out of range",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           testing::WriteText(d / j["mesh"].get<std::string>(),
                              "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 9/3\n");
         });
         return "info " + Q(json);
       },
       kBadInput, {"mesh.obj:7"}},
      {"missing mesh under a path with spaces and non-ASCII characters",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(
             w, [](Json& j, const fs::path&) { j["mesh"] = "maillage déjà vu.obj"; },
             "dossier avec espaces/captüre ✓");
         return "info " + Q(json);
       },
       kBadInput, {"dossier avec espaces/captüre ✓", "maillage déjà vu.obj", "mesh"}},
      {"--atlas-res 0", [](const fs::path&) { return "info " + Q(TinyCapture()) + " --atlas-res 0"; },
       kUsage, {"--atlas-res"}},
  };
  RunCases(cases);
}

// A capture under a path with spaces and non-ASCII characters is read like any other.
TEST(BadInputCorpus, InfoReadsPathsWithSpacesAndNonAscii) {
  ScratchDir work, logs;
  const fs::path dir = CopyTo(TinyCapture(), work.path(), "dossier avec espaces/captüre ✓");
  const CliResult r = RunCli("info " + Q(dir / "capture.json"), logs);
  EXPECT_EQ(r.exit_code, 0) << r.err;
}

// ---- synth: flags and output folders ----------------------------------------------------------

TEST(BadInputCorpus, Synth) {
  const std::string small = " --texels 500 --image-size 16 --cameras 1 --lights 1 --steps 1";
  std::vector<Case> cases = {
      {"--noise nan", [&](const fs::path& w) { return "synth --out " + Q(w / "out") + " --noise nan"; },
       kUsage, {"--noise"}},
      {"--noise inf", [&](const fs::path& w) { return "synth --out " + Q(w / "out") + " --noise inf"; },
       kUsage, {"--noise"}},
      {"--saturation -1",
       [&](const fs::path& w) { return "synth --out " + Q(w / "out") + " --saturation -1"; },
       kUsage, {"--saturation"}},
      {"--image-size -4", [&](const fs::path& w) { return "synth --out " + Q(w / "out") + " --image-size -4"; },
       kUsage, {"--image-size"}},
      {"--texels -5", [&](const fs::path& w) { return "synth --out " + Q(w / "out") + " --texels -5"; },
       kUsage, {"--texels"}},
      {"--materials with an unknown name",
       [&](const fs::path& w) { return "synth --out " + Q(w / "out") + " --materials matte,velvet"; },
       kUsage, {"velvet"}},
      {"output folder not writable (/proc)",
       [&](const fs::path&) { return "synth --quiet --out /proc/reflcap_bad_input_corpus" + small; },
       kBadInput, {"reflcap_bad_input_corpus", "cannot create folder"}},
      // /bin/sh's ulimit -f counts 512-byte blocks: 32 = 16 KiB, 64 = 32 KiB.
      {"disk full (ulimit -f: 16 KiB, SIGXFSZ ignored)",
       [&](const fs::path& w) { return "synth --quiet --out " + Q(w / "out") + small; },
       kInternal, {".out.tmp", "write failed"}, "trap '' XFSZ; ulimit -f 32; "},
  };
  if (!RunningAsRoot()) {  // root writes through permission bits
    cases.push_back({"read-only output folder",
                     [&](const fs::path& w) {
                       fs::create_directories(w / "ro");
                       fs::permissions(w / "ro", fs::perms::owner_read | fs::perms::owner_exec);
                       return "synth --quiet --out " + Q(w / "ro/out") + small;
                     },
                     kInternal, {"ro/", "cannot create folder"}});
  }
  RunCases(cases);
}

// ---- resample: captures and flags ------------------------------------------------------------

TEST(BadInputCorpus, Resample) {
  const std::vector<Case> cases = {
      {"--min-cos 2", [](const fs::path& w) {
         return "resample " + Q(TinyCapture()) + " --out " + Q(w / "out") + " --min-cos 2"; },
       kUsage, {"--min-cos"}},
      {"--min-cos nan", [](const fs::path& w) {
         return "resample " + Q(TinyCapture()) + " --out " + Q(w / "out") + " --min-cos nan"; },
       kUsage, {"--min-cos"}},
      {"--split banana", [](const fs::path& w) {
         return "resample " + Q(TinyCapture()) + " --out " + Q(w / "out") + " --split banana"; },
       kUsage, {"--split"}},
      {"--atlas-res -1", [](const fs::path& w) {
         return "resample " + Q(TinyCapture()) + " --out " + Q(w / "out") + " --atlas-res -1"; },
       kUsage, {"--atlas-res"}},
      {"photograph with a wrong channel set (A only)",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           const Json& cam = j["cameras"][0];
           const int width = cam["width"], height = cam["height"];
           for (Json& image : j["images"]) {
             if (image["camera"] == cam["id"] && image["split"] == "train") {
               WriteBytes(d / image["file"].get<std::string>(),
                          testing::RawExr(width, height, {{"A", std::vector<float>(size_t(width) * height, 1.0f)}}));
               break;
             }
           }
         });
         return "resample " + Q(json) + " --out " + Q(w / "out");
       },
       kBadInput, {"capture.json", "images[", ".file"}},
      {"variance image holding NaN and Inf (--variance-weights)",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           const Json& cam = j["cameras"][0];
           const int width = cam["width"], height = cam["height"];
           auto planes = Rgb(width, height, 1e-4f);
           planes["G"][5] = std::numeric_limits<float>::quiet_NaN();
           planes["B"][7] = std::numeric_limits<float>::infinity();
           WriteBytes(d / "var0.exr", testing::RawExr(width, height, planes));
           for (Json& image : j["images"]) {
             if (image["camera"] == cam["id"] && image["split"] == "train") {
               image["variance"] = "var0.exr";
               break;
             }
           }
         });
         return "resample " + Q(json) + " --out " + Q(w / "out") + " --variance-weights";
       },
       kBadInput, {"capture.json", ".variance", "var0.exr"}},
      {"capture with a missing photograph",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path& d) {
           fs::remove(d / j["images"][0]["file"].get<std::string>());
         });
         return "resample " + Q(json) + " --out " + Q(w / "out");
       },
       kBadInput, {"capture.json", "images[0].file"}},
      {"disk full while writing chunks (ulimit -f: 32 KiB, SIGXFSZ ignored)",
       [](const fs::path& w) { return "resample --quiet " + Q(TinyCapture()) + " --out " + Q(w / "out"); },
       kInternal, {"chunk_00000.rcs", "write failed"}, "trap '' XFSZ; ulimit -f 64; "},
  };
  RunCases(cases);
}

// ---- fit: sample stores and flags -------------------------------------------------------------

TEST(BadInputCorpus, Fit) {
  auto store = [](const fs::path& w) { return CopyTo(TinySamples(), w, "samples"); };
  const std::vector<Case> cases = {
      {"store without store.json",
       [&](const fs::path& w) {
         const fs::path s = store(w);
         fs::remove(s / "store.json");
         return "fit " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"store.json"}},
      {"store.json min_cos = 1e999",
       [&](const fs::path& w) {
         const fs::path s = store(w);
         Json j = ReadJson(s / "store.json");
         j["min_cos"] = 123.25;
         WriteJson(s / "store.json", j);
         ReplaceInFile(s / "store.json", "123.25", "1e999");
         return "fit " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"store.json", "not valid JSON"}},
      {"store.json chunks disagreeing with texels",
       [&](const fs::path& w) {
         const fs::path s = store(w);
         Json j = ReadJson(s / "store.json");
         j["chunks"] = j["chunks"].get<int>() + 3;
         WriteJson(s / "store.json", j);
         return "fit " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"store.json", "chunks"}},
      {"truncated atlas.bin",
       [&](const fs::path& w) {
         const fs::path s = store(w);
         fs::resize_file(s / "atlas.bin", fs::file_size(s / "atlas.bin") - 4);
         return "fit " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"atlas.bin"}},
      {"0-byte chunk",
       [&](const fs::path& w) {
         const fs::path s = store(w);
         fs::resize_file(s / "chunk_00000.rcs", 0);
         return "fit " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"chunk_00000.rcs"}},
      {"--loss-scale nan", [&](const fs::path& w) {
         return "fit " + Q(TinySamples()) + " --out " + Q(w / "out") + " --loss-scale nan"; },
       kUsage, {"--loss-scale"}},
      {"--backend banana", [&](const fs::path& w) {
         return "fit " + Q(TinySamples()) + " --out " + Q(w / "out") + " --backend banana"; },
       kUsage, {"--backend"}},
      {"--threads -3", [&](const fs::path& w) {
         return "fit " + Q(TinySamples()) + " --out " + Q(w / "out") + " --threads -3"; },
       kUsage, {"--threads"}},
  };
  RunCases(cases);
}

// ---- render and validate: fits, renders and flags -----------------------------------------------

TEST(BadInputCorpus, RenderAndValidate) {
  auto fit = [](const fs::path& w) { return CopyTo(TinyFit(), w, "fit"); };
  auto params_size = [] {
    auto info = ReadExrInfo(TinyFit() / "params.exr");
    REFLCAP_CHECK(info.ok()) << info.status().ToString();
    return std::make_pair(info->width, info->height);
  };
  const std::vector<Case> cases = {
      {"fit without params.exr",
       [&](const fs::path& w) {
         const fs::path f = fit(w);
         fs::remove(f / "params.exr");
         return "render " + Q(TinyCapture()) + " " + Q(f) + " --out " + Q(w / "out") + " --backend cpu";
       },
       kBadInput, {"params.exr"}},
      {"params.exr without rho_d channels",
       [&](const fs::path& w) {
         const fs::path f = fit(w);
         const auto [width, height] = params_size();
         WriteBytes(f / "params.exr", testing::RawExr(width, height, Rgb(width, height, 0.5f)));
         return "render " + Q(TinyCapture()) + " " + Q(f) + " --out " + Q(w / "out") + " --backend cpu";
       },
       kBadInput, {"params.exr", "rho_d.R"}},
      {"params.exr cut in half",
       [&](const fs::path& w) {
         const fs::path f = fit(w);
         fs::resize_file(f / "params.exr", fs::file_size(f / "params.exr") / 2);
         return "render " + Q(TinyCapture()) + " " + Q(f) + " --out " + Q(w / "out") + " --backend cpu";
       },
       kBadInput, {"params.exr"}},
      {"params.exr holding NaN and Inf",
       [&](const fs::path& w) {
         const fs::path f = fit(w);
         const auto [width, height] = params_size();
         std::map<std::string, std::vector<float>> planes;
         for (const char* c : {"rho_d.R", "rho_d.G", "rho_d.B"}) {
           planes[c] = std::vector<float>(size_t(width) * height, std::numeric_limits<float>::quiet_NaN());
         }
         planes["rho_d.G"].assign(planes["rho_d.G"].size(), std::numeric_limits<float>::infinity());
         WriteBytes(f / "params.exr", testing::RawExr(width, height, planes));
         return "render " + Q(TinyCapture()) + " " + Q(f) + " --out " + Q(w / "out") + " --backend cpu";
       },
       0, {"params.exr", "non-finite parameters", "render black"}},
      {"--supersample 0", [&](const fs::path& w) {
         return "render " + Q(TinyCapture()) + " " + Q(TinyFit()) + " --out " + Q(w / "out") +
                " --supersample 0"; },
       kUsage, {"--supersample"}},
      {"render --psf 9", [&](const fs::path& w) {
         return "render " + Q(TinyCapture()) + " " + Q(TinyFit()) + " --out " + Q(w / "out") +
                " --psf 9"; },
       kUsage, {"--psf"}},
      {"render --height-field banana", [&](const fs::path& w) {
         return "render " + Q(TinyCapture()) + " " + Q(TinyFit()) + " --out " + Q(w / "out") +
                " --height-field banana"; },
       kUsage, {"--height-field"}},
      {"render --split banana", [&](const fs::path& w) {
         return "render " + Q(TinyCapture()) + " " + Q(TinyFit()) + " --out " + Q(w / "out") +
                " --split banana"; },
       kUsage, {"--split"}},
      {"validate: a render missing",
       [&](const fs::path& w) {
         const fs::path renders = CopyTo(TinyRenders(), w, "renders");
         for (const auto& e : fs::directory_iterator(renders / "images")) {
           if (e.path().extension() == ".exr") {
             fs::remove(e.path());
             break;
           }
         }
         return "validate " + Q(TinyCapture()) + " " + Q(renders) + " --out " + Q(w / "out");
       },
       kBadInput, {"renders", ".exr"}},
      {"validate: a render of the wrong size",
       [&](const fs::path& w) {
         const fs::path renders = CopyTo(TinyRenders(), w, "renders");
         for (const auto& e : fs::directory_iterator(renders / "images")) {
           if (e.path().extension() == ".exr") {
             WriteBytes(e.path(), testing::RawExr(5, 7, Rgb(5, 7, 0.25f)));
             break;
           }
         }
         return "validate " + Q(TinyCapture()) + " " + Q(renders) + " --out " + Q(w / "out");
       },
       kBadInput, {"renders", "5x7"}},
      {"validate: RENDERS is a file",
       [&](const fs::path& w) {
         testing::WriteText(w / "renders.txt", "not a folder");
         return "validate " + Q(TinyCapture()) + " " + Q(w / "renders.txt") + " --out " + Q(w / "out");
       },
       kBadInput, {"renders.txt", "not a folder"}},
  };
  RunCases(cases);
}

// ---- run and bench: flags and outputs -----------------------------------------------------------

TEST(BadInputCorpus, RunAndBench) {
  const std::vector<Case> cases = {
      {"run: capture.json missing",
       [](const fs::path& w) { return "run " + Q(w / "nothing/capture.json") + " --out " + Q(w / "out"); },
       kBadInput, {"nothing/capture.json"}},
      {"run: capture with a duplicate camera id",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["cameras"][1]["id"] = j["cameras"][0]["id"];
         });
         return "run " + Q(json) + " --out " + Q(w / "out");
       },
       kBadInput, {"capture.json", "cameras[1].id"}},
      {"run: a camera's pixel_filter neither area nor point",
       [](const fs::path& w) {
         const fs::path json = EditedCapture(w, [](Json& j, const fs::path&) {
           j["cameras"][1]["pixel_filter"] = "gaussian";
         });
         return "run " + Q(json) + " --out " + Q(w / "out");
       },
       kBadInput, {"capture.json", "cameras[1].pixel_filter", "gaussian"}},
      {"run: --pixel-filter banana", [](const fs::path& w) {
         return "run " + Q(TinyCapture()) + " --out " + Q(w / "out") + " --pixel-filter banana"; },
       kUsage, {"--pixel-filter"}},
      {"run: --psf banana", [](const fs::path& w) {
         return "run " + Q(TinyCapture()) + " --out " + Q(w / "out") + " --psf banana"; },
       kUsage, {"--psf"}},
      {"run: output under /proc",
       [](const fs::path&) { return "run --quiet " + Q(TinyCapture()) + " --out /proc/reflcap_corpus_run"; },
       kBadInput, {"reflcap_corpus_run", "cannot create folder"}},
      {"bench: --sweeps banana", [](const fs::path& w) {
         return "bench --out " + Q(w / "out") + " --sweeps fit,banana"; },
       kUsage, {"banana"}},
      {"bench: --backends banana", [](const fs::path& w) {
         return "bench --out " + Q(w / "out") + " --backends cpu,banana"; },
       kUsage, {"banana"}},
      {"bench: --threads -2", [](const fs::path& w) {
         return "bench --out " + Q(w / "out") + " --threads -2"; },
       kUsage, {"threads", "-2"}},
  };
  RunCases(cases);
}

// ---- import-diligent ----------------------------------------------------------------------------

// A minimal DiLiGenT object folder: `lights` 8x8 16-bit photographs, the three text files, a
// mask and a normal map.
fs::path DiligentObject(const fs::path& dir, int lights) {
  constexpr int kSize = 8;
  fs::create_directories(dir);
  std::ostringstream names, dirs, ints;
  for (int i = 0; i < lights; ++i) {
    const std::string name = "00" + std::to_string(i + 1) + ".png";
    names << name << "\n";
    dirs << "0.1 " << 0.1 * i << " 0.9\n";
    ints << "1 1 1\n";
    REFLCAP_CHECK(WritePng(dir / name, Image(kSize, kSize, 3, 0.5f), 16).ok());
  }
  testing::WriteText(dir / "filenames.txt", names.str());
  testing::WriteText(dir / "light_directions.txt", dirs.str());
  testing::WriteText(dir / "light_intensities.txt", ints.str());
  Image normals(kSize, kSize, 3, 0.0f);
  for (size_t p = 0; p < normals.PixelCount(); ++p) normals.data[p * 3 + 2] = 1.0f;
  REFLCAP_CHECK(WriteExr(dir / "normals.exr", normals).ok());
  REFLCAP_CHECK(WritePng(dir / "mask.png", Image(kSize, kSize, 1, 1.0f)).ok());
  return dir;
}

// merge (issue 19) and export (issue 20): parts that do not belong together, corrupt parts, and
// the flags.
TEST(BadInputCorpus, MergeAndExport) {
  const std::vector<Case> cases = {
      {"merge: no parts", [](const fs::path& w) { return "merge --out " + Q(w / "out"); },
       kUsage, {"PARTS"}},
      {"merge: a folder that is not a part",
       [](const fs::path& w) { return "merge " + Q(TinyFit()) + " --out " + Q(w / "out"); },
       kBadInput, {"fit", "not a part"}},
      {"merge: a shard missing",
       [](const fs::path& w) { return "merge " + Q(TinyResamplePart(0)) + " --out " + Q(w / "out"); },
       kBadInput, {"shard 1 is missing"}},
      {"merge: the same shard twice",
       [](const fs::path& w) {
         return "merge " + Q(TinyResamplePart(0)) + " " + Q(TinyResamplePart(0)) + " --out " + Q(w / "out");
       },
       kBadInput, {"resample_part.json", "shard 0 is also"}},
      {"merge: resample_part.json not JSON",
       [](const fs::path& w) {
         const fs::path part = CopyTo(TinyResamplePart(1), w, "part1");
         testing::WriteText(part / "resample_part.json", "{\"format\": ");
         return "merge " + Q(TinyResamplePart(0)) + " " + Q(part) + " --out " + Q(w / "out");
       },
       kBadInput, {"part1/resample_part.json", "format"}},
      {"merge: a truncated chunk in a part",
       [](const fs::path& w) {
         const fs::path part = CopyTo(TinyResamplePart(1), w, "part1");
         fs::resize_file(part / "chunk_00000.rcs", fs::file_size(part / "chunk_00000.rcs") / 2);
         return "merge " + Q(TinyResamplePart(0)) + " " + Q(part) + " --out " + Q(w / "out");
       },
       kBadInput, {"part1/chunk_00000.rcs", "truncated"}},
      {"merge --link: parts that are not resample parts",
       [](const fs::path& w) { return "merge " + Q(TinyFit()) + " --out " + Q(w / "out") + " --link"; },
       kUsage, {"--link", "resample parts"}},
      {"fit: a linked store whose part has gone",
       [](const fs::path& w) {
         const fs::path p0 = CopyTo(TinyResamplePart(0), w, "p0");
         const fs::path p1 = CopyTo(TinyResamplePart(1), w, "p1");
         ScratchDir logs;
         const CliResult r = RunCli("merge " + Q(p0) + " " + Q(p1) + " --link --out " + Q(w / "linked"), logs);
         REFLCAP_CHECK(r.exit_code == 0) << r.err;
         fs::remove_all(p1);
         return "fit " + Q(w / "linked") + " --out " + Q(w / "out");
       },
       kBadInput, {"linked/store.json", "parts[1]", "p1"}},
      {"fit: --shard 2/2", [](const fs::path& w) {
         return "fit " + Q(TinySamples()) + " --out " + Q(w / "out") + " --shard 2/2"; },
       kUsage, {"--shard"}},
      {"fit: a resample part alone",
       [](const fs::path& w) { return "fit " + Q(TinyResamplePart(0)) + " --out " + Q(w / "out"); },
       kBadInput, {"resample_part0", "reflcap merge"}},
      {"export: no --gltf",
       [](const fs::path&) { return "export " + Q(TinyFit()); },
       kUsage, {"--gltf"}},
      {"export: a folder without params.exr",
       [](const fs::path& w) {
         fs::create_directories(w / "empty fit");
         return "export " + Q(w / "empty fit") + " --gltf " + Q(w / "out.glb");
       },
       kBadInput, {"empty fit", "params.exr"}},
  };
  RunCases(cases);
}

TEST(BadInputCorpus, ImportDiligent) {
  const std::vector<Case> cases = {
      {"light_directions.txt with a short line",
       [](const fs::path& w) {
         const fs::path d = DiligentObject(w / "ball", 4);
         testing::WriteText(d / "light_directions.txt", "0 0 1\n0 0.1 0.9\n0.2 0.9\n0 0 1\n");
         return "import-diligent " + Q(d) + " --out " + Q(w / "out");
       },
       kBadInput, {"light_directions.txt:3"}},
      {"light_intensities.txt holding nan",
       [](const fs::path& w) {
         const fs::path d = DiligentObject(w / "ball", 4);
         testing::WriteText(d / "light_intensities.txt", "1 1 1\n1 nan 1\n1 1 1\n1 1 1\n");
         return "import-diligent " + Q(d) + " --out " + Q(w / "out");
       },
       kBadInput, {"light_intensities.txt:2"}},
      {"0-byte photograph",
       [](const fs::path& w) {
         const fs::path d = DiligentObject(w / "ball", 4);
         fs::resize_file(d / "002.png", 0);
         return "import-diligent " + Q(d) + " --out " + Q(w / "out");
       },
       kBadInput, {"002.png"}},
      {"normals.exr holding NaN",
       [](const fs::path& w) {
         const fs::path d = DiligentObject(w / "ball", 4);
         auto planes = Rgb(8, 8, 0.0f);
         planes["B"].assign(64, std::numeric_limits<float>::quiet_NaN());
         WriteBytes(d / "normals.exr", testing::RawExr(8, 8, planes));
         return "import-diligent " + Q(d) + " --out " + Q(w / "out");
       },
       kBadInput, {"normals.exr", "finite"}},
      {"--holdout-every 0", [](const fs::path& w) {
         const fs::path d = DiligentObject(w / "ball", 4);
         return "import-diligent " + Q(d) + " --out " + Q(w / "out") + " --holdout-every 0"; },
       kUsage, {"--holdout-every"}},
  };
  RunCases(cases);
}

// ---- calibrate, hdr, scan: the acquisition formats ----------------------------------------------

// The seed documents of the fuzz corpus (tests/fuzz/corpus) are valid calib/1, brackets/1 and
// structured_light/1 files whose photos do not exist.
Json Seed(const std::string& target, const std::string& name) {
  return ReadJson(fs::path(REFLCAP_FUZZ_CORPUS_DIR) / target / name);
}

TEST(BadInputCorpus, Calibrate) {
  auto calib = [](const fs::path& w, const std::function<void(Json&)>& edit) {
    Json j = Seed("calib", "cuboid_small.json");
    edit(j);
    WriteJson(w / "calib.json", j);
    fs::create_directories(w / "out");  // calibrate writes into an existing folder
    return w / "calib.json";
  };
  const std::vector<Case> cases = {
      {"intrinsics: duplicate camera id",
       [&](const fs::path& w) {
         const fs::path c = calib(w, [](Json& j) { j["cameras"][1]["id"] = j["cameras"][0]["id"]; });
         return "calibrate intrinsics " + Q(c) + " --out " + Q(w / "out/intrinsics.json");
       },
       kBadInput, {"calib.json", "cameras[1].id"}},
      {"intrinsics: K entry 1e999",
       [&](const fs::path& w) {
         const fs::path c = calib(w, [](Json& j) { j["cameras"][0]["K"][0][0] = 123.25; });
         ReplaceInFile(c, "123.25", "1e999");
         return "calibrate intrinsics " + Q(c) + " --out " + Q(w / "out/intrinsics.json");
       },
       kBadInput, {"calib.json", "cameras[0].K"}},
      {"intrinsics: photo missing",
       [&](const fs::path& w) {
         const fs::path c = calib(w, [](Json&) {});
         return "calibrate intrinsics " + Q(c) + " --out " + Q(w / "out/intrinsics.json");
       },
       kBadInput, {"calib.json", "intrinsics_images[0].file"}},
      {"turntable: malformed --intrinsics file",
       [&](const fs::path& w) {
         const fs::path c = calib(w, [](Json&) {});
         Json in = Seed("intrinsics", "two_cameras.json");
         in["cameras"][0]["width"] = -640;
         WriteJson(w / "intr.json", in);
         return "calibrate turntable " + Q(c) + " --out " + Q(w / "out/rig.json") + " --intrinsics " +
                Q(w / "intr.json");
       },
       kBadInput, {"intr.json", "cameras[0].width"}},
      {"turntable: cuboid face square_m = -inf",
       [&](const fs::path& w) {
         const fs::path c = calib(w, [](Json& j) { j["cuboid"]["faces"][1]["square_m"] = 123.25; });
         ReplaceInFile(c, "123.25", "-1e999");
         return "calibrate turntable " + Q(c) + " --out " + Q(w / "out/rig.json");
       },
       kBadInput, {"calib.json", "cuboid.faces[1].square_m"}},
  };
  RunCases(cases);
}

// Brackets seed with its cameras shrunk to 8x8 and every exposure written as an 8-bit RGB PNG
// of that size (so the checks reach the photos themselves).
fs::path Brackets(const fs::path& w, const std::function<void(Json&, const fs::path&)>& edit) {
  constexpr int kSize = 8;
  Json j = Seed("brackets", "suzanne_small.json");
  for (Json& cam : j["cameras"]) {
    cam["width"] = kSize;
    cam["height"] = kSize;
    cam["K"] = Json::array({Json::array({10.0, 0.0, 4.0}), Json::array({0.0, 10.0, 4.0}),
                            Json::array({0.0, 0.0, 1.0})});
  }
  j.erase("source_capture");
  for (Json& photo : j["photos"]) {
    photo.erase("source_hdr");
    for (const Json& e : photo["exposures"]) {
      const fs::path png = w / e["file"].get<std::string>();
      fs::create_directories(png.parent_path());
      REFLCAP_CHECK(WritePng(png, Image(kSize, kSize, 3, 0.5f)).ok());
    }
  }
  testing::WriteText(w / "quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n"
                                     "vt 0 1\nf 1/1 2/2 3/3 4/4\n");
  edit(j, w);
  WriteJson(w / "brackets.json", j);
  return w / "brackets.json";
}

TEST(BadInputCorpus, Hdr) {
  const std::vector<Case> cases = {
      {"duplicate photo id",
       [](const fs::path& w) {
         const fs::path b = Brackets(w, [](Json& j, const fs::path&) { j["photos"][1]["id"] = j["photos"][0]["id"]; });
         return "hdr " + Q(b) + " --out " + Q(w / "out") + " --mesh " + Q(w / "quad.obj") + " --no-chart";
       },
       kBadInput, {"brackets.json", "photos[1].id"}},
      {"exposures not increasing",
       [](const fs::path& w) {
         const fs::path b = Brackets(w, [](Json& j, const fs::path&) {
           j["photos"][0]["exposures"][1]["exposure_s"] = j["photos"][0]["exposures"][0]["exposure_s"];
         });
         return "hdr " + Q(b) + " --out " + Q(w / "out") + " --mesh " + Q(w / "quad.obj") + " --no-chart";
       },
       kBadInput, {"brackets.json", "photos[0].exposures[1].exposure_s"}},
      {"exposure_s = 1e999",
       [](const fs::path& w) {
         const fs::path b = Brackets(w, [](Json& j, const fs::path&) {
           j["photos"][0]["exposures"].back()["exposure_s"] = 123.25;
         });
         ReplaceInFile(b, "123.25", "1e999");
         return "hdr " + Q(b) + " --out " + Q(w / "out") + " --mesh " + Q(w / "quad.obj") + " --no-chart";
       },
       kBadInput, {"brackets.json", "1e999"}},
      {"exposure PNG at 16 bits (values off the 8-bit grid)",
       [](const fs::path& w) {
         const fs::path b = Brackets(w, [](Json& j, const fs::path& d) {
           const fs::path png = d / j["photos"][0]["exposures"][2]["file"].get<std::string>();
           REFLCAP_CHECK(WritePng(png, Image(8, 8, 3, 0.3f), 16).ok());
         });
         return "hdr " + Q(b) + " --out " + Q(w / "out") + " --mesh " + Q(w / "quad.obj") + " --no-chart";
       },
       kBadInput, {"brackets.json", "photos[0].exposures[2].file"}},
      {"0-byte exposure PNG",
       [](const fs::path& w) {
         const fs::path b = Brackets(w, [](Json& j, const fs::path& d) {
           fs::resize_file(d / j["photos"][1]["exposures"][0]["file"].get<std::string>(), 0);
         });
         return "hdr " + Q(b) + " --out " + Q(w / "out") + " --mesh " + Q(w / "quad.obj") + " --no-chart";
       },
       kBadInput, {"brackets.json", "photos[1].exposures[0].file"}},
      {"exposure PNG of the wrong size",
       [](const fs::path& w) {
         const fs::path b = Brackets(w, [](Json& j, const fs::path& d) {
           const fs::path png = d / j["photos"][0]["exposures"][0]["file"].get<std::string>();
           REFLCAP_CHECK(WritePng(png, Image(9, 8, 3, 0.5f)).ok());
         });
         return "hdr " + Q(b) + " --out " + Q(w / "out") + " --mesh " + Q(w / "quad.obj") + " --no-chart";
       },
       kBadInput, {"brackets.json", "photos[0].exposures[0].file", "9x8"}},
  };
  RunCases(cases);
}

TEST(BadInputCorpus, Scan) {
  auto scan = [](const fs::path& w, const std::function<void(Json&)>& edit) {
    Json j = Seed("scan_spec", "suzanne_small.json");
    edit(j);
    WriteJson(w / "scan.json", j);
    return w / "scan.json";
  };
  const std::vector<Case> cases = {
      {"duplicate turntable angle",
       [&](const fs::path& w) {
         const fs::path s = scan(w, [](Json& j) { j["turntable_angles_deg"][1] = j["turntable_angles_deg"][0]; });
         return "scan " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"scan.json", "turntable_angles_deg"}},
      {"angle = 1e999",
       [&](const fs::path& w) {
         const fs::path s = scan(w, [](Json& j) { j["turntable_angles_deg"][1] = 123.25; });
         ReplaceInFile(s, "123.25", "1e999");
         return "scan " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"scan.json", "number overflow", "1e999"}},
      {"a Gray code image missing at one angle",
       [&](const fs::path& w) {
         const fs::path s = scan(w, [](Json& j) {
           Json images = Json::array();
           bool dropped = false;
           for (const Json& image : j["images"]) {
             if (!dropped && image["pattern"] == "gray_col_b3") {
               dropped = true;
               continue;
             }
             images.push_back(image);
           }
           j["images"] = images;
         });
         return "scan " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"scan.json", "gray_col_b3"}},
      {"photos missing",
       [&](const fs::path& w) {
         const fs::path s = scan(w, [](Json&) {});
         return "scan " + Q(s) + " --out " + Q(w / "out");
       },
       kBadInput, {"scan.json", "images[0]"}},
      {"--atlas-res 0",
       [&](const fs::path& w) {
         const fs::path s = scan(w, [](Json&) {});
         return "scan " + Q(s) + " --out " + Q(w / "out") + " --atlas-res 0";
       },
       kUsage, {"atlas resolution", "got 0"}},
  };
  RunCases(cases);
}

}  // namespace
}  // namespace reflcap
