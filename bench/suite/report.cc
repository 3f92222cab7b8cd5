// `reflcap bench`'s outputs (suite.h): bench_results.json, one CSV per sweep, SVG plots and an
// index.html that shows them with the records' tables. The CSV files are generated from the same
// JSON records, so their columns are exactly the JSON fields (bench/README.md).
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "bench/suite/suite.h"
#include "bench/suite/svg_plot.h"
#include "engine/core/atomic_file.h"

namespace reflcap::benchsuite {
namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;
namespace {

// Schema version of bench_results.json (bench/README.md).
constexpr char kFormat[] = "reflcap-bench/1";

// NaN and infinities become JSON null (nlohmann does the same; explicit for readers).
Json Number(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

void AddAccuracy(const Accuracy& a, Json* j) {
  (*j)["median_rel_error_rho_d"] = Number(a.median_rel_error_rho_d);
  (*j)["median_rel_error_n"] = Number(a.median_rel_error_n);
  (*j)["median_rel_error_peak"] = Number(a.median_rel_error_peak);
  (*j)["converged_fraction"] = Number(a.converged_fraction);
  (*j)["mean_iterations"] = Number(a.mean_iterations);
  (*j)["holdout_psnr_db"] = Number(a.holdout_psnr_db);
}

void AddValidity(bool valid, const std::string& reason, Json* j) {
  (*j)["valid"] = valid;
  (*j)["invalid_reason"] = reason;
}

Json ToJson(const FitRecord& r) {
  Json j;
  j["backend"] = r.backend;
  j["samples_per_texel"] = r.samples_per_texel;
  j["texels"] = r.texels;
  j["fits"] = r.fits;
  j["repetitions"] = r.repetitions;
  j["seconds"] = Number(r.seconds);
  j["fits_per_second"] = Number(r.fits_per_second);
  j["fits_per_cpu_second"] = Number(r.fits_per_cpu_second);
  if (r.gflops > 0) {
    j["gflops"] = Number(r.gflops);
    j["peak_fraction"] = Number(r.peak_fraction);
  }
  AddAccuracy(r.accuracy, &j);
  AddValidity(r.valid, r.invalid_reason, &j);
  return j;
}

Json ToJson(const SpeedErrorRecord& r) {
  Json j;
  j["backend"] = r.backend;
  j["max_iterations"] = r.max_iterations;
  j["tolerance"] = r.tolerance;
  j["samples_per_texel"] = r.samples_per_texel;
  j["texels"] = r.texels;
  j["seconds"] = Number(r.seconds);
  j["fits_per_second"] = Number(r.fits_per_second);
  j["fits_per_cpu_second"] = Number(r.fits_per_cpu_second);
  AddAccuracy(r.accuracy, &j);
  j["pareto"] = r.pareto;
  AddValidity(r.valid, r.invalid_reason, &j);
  return j;
}

Json ToJson(const InitRecord& r) {
  Json j;
  j["backend"] = r.backend;
  j["init"] = r.init;
  j["samples_per_texel"] = r.samples_per_texel;
  j["texels"] = r.texels;
  j["seconds"] = Number(r.seconds);
  j["fits_per_second"] = Number(r.fits_per_second);
  j["fits_per_cpu_second"] = Number(r.fits_per_cpu_second);
  AddAccuracy(r.accuracy, &j);
  AddValidity(r.valid, r.invalid_reason, &j);
  return j;
}

Json ToJson(const ScalingRecord& r) {
  Json j;
  j["texels_target"] = r.texels_target;
  j["texels"] = r.texels;
  j["image_size"] = r.image_size;
  j["images"] = r.images;
  j["stage"] = r.stage;
  j["seconds"] = Number(r.seconds);
  j["texels_per_second"] = Number(r.texels_per_second);
  j["peak_rss_bytes"] = r.peak_rss_bytes;
  j["peak_rss_mib"] = Number(double(r.peak_rss_bytes) / (1 << 20));
  j["start_rss_bytes"] = r.start_rss_bytes;
  j["detail"] = r.detail;
  AddValidity(r.valid, r.invalid_reason, &j);
  return j;
}

Json ToJson(const ViewpointRecord& r) {
  Json j;
  j["cameras"] = r.cameras;
  j["steps"] = r.steps;
  j["lights"] = r.lights;
  j["viewpoints"] = r.viewpoints;
  j["train_images"] = r.train_images;
  j["holdout_images"] = r.holdout_images;
  j["texels"] = r.texels;
  j["texels_with_samples_fraction"] = Number(r.texels_with_samples_fraction);
  j["holdout_psnr_db"] = Number(r.holdout_psnr_db);
  j["noise_bound_psnr_db"] = r.noise_bound_psnr_db > 0 ? Number(r.noise_bound_psnr_db) : Json(nullptr);
  j["median_rel_error_rho_d"] = Number(r.median_rel_error_rho_d);
  j["median_rel_error_n"] = Number(r.median_rel_error_n);
  j["lobe_fraction"] = Number(r.lobe_fraction);
  j["seconds"] = Number(r.seconds);
  AddValidity(r.valid, r.invalid_reason, &j);
  return j;
}

template <typename Record>
Json ToJsonList(const std::vector<Record>& records) {
  Json list = Json::array();
  for (const Record& r : records) list.push_back(ToJson(r));
  return list;
}

Json BuildJson(const SuiteResults& r) {
  Json j;
  j["format"] = kFormat;
  j["machine"] = {{"cpu_model", r.machine.cpu_model},
                  {"cores", r.machine.cores},
                  {"ram_bytes", r.machine.ram_bytes},
                  {"os", r.machine.os},
                  {"summary", r.machine.ToString()}};
  j["device"] = r.device;
  j["device_available"] = r.device_available;
  j["device_mad_gflops"] = Number(r.device_mad_gflops);
  j["device_copy_gbps"] = Number(r.device_copy_gbps);
  j["date"] = r.date;
  j["reflcap_version"] = r.reflcap_version;
  j["quick"] = r.scale == "quick";
  j["scale"] = r.scale;
  j["total_seconds"] = Number(r.total_seconds);
  j["peak_rss_method"] = r.rss_method;
  Json omitted = Json::array();
  for (const OmittedBackend& o : r.omitted) omitted.push_back({{"backend", o.backend}, {"reason", o.reason}});
  j["backends_omitted"] = omitted;
  j["fit"] = ToJsonList(r.fit);
  j["speed_vs_error"] = ToJsonList(r.speed_vs_error);
  j["scaling"] = ToJsonList(r.scaling);
  j["init_schemes"] = ToJsonList(r.init_schemes);
  j["viewpoints"] = ToJsonList(r.viewpoints);
  j["notes"] = r.notes;
  return j;
}

std::string CsvField(const Json& v) {
  if (v.is_null()) return "";
  if (v.is_string()) {
    const std::string s = v.get<std::string>();
    if (s.find_first_of(",\"\n") == std::string::npos) return s;
    std::string q = "\"";
    for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
    return q + "\"";
  }
  return v.dump();
}

// One header line (the keys of the records) and one line per record; header only when empty.
std::string ToCsv(const Json& list, const std::vector<std::string>& header_if_empty) {
  std::ostringstream out;
  std::vector<std::string> keys = header_if_empty;
  if (!list.empty()) {
    keys.clear();
    for (auto it = list[0].begin(); it != list[0].end(); ++it) keys.push_back(it.key());
  }
  for (size_t k = 0; k < keys.size(); ++k) out << (k ? "," : "") << keys[k];
  out << "\n";
  for (const Json& rec : list) {
    for (size_t k = 0; k < keys.size(); ++k) {
      out << (k ? "," : "") << (rec.contains(keys[k]) ? CsvField(rec[keys[k]]) : "");
    }
    out << "\n";
  }
  return out.str();
}

// The keys of an empty sweep's CSV: those of a default record.
template <typename Record>
std::vector<std::string> KeysOf() {
  std::vector<std::string> keys;
  const Json j = ToJson(Record{});
  for (auto it = j.begin(); it != j.end(); ++it) keys.push_back(it.key());
  return keys;
}

struct NamedPlot {
  std::string file, caption;
  Plot plot;
};

// Series in first-seen order of `key(record)`, valid records only.
template <typename Record, typename Key, typename X, typename Y>
std::vector<PlotSeries> GroupSeries(const std::vector<Record>& records, Key key, X x, Y y) {
  std::vector<PlotSeries> series;
  std::map<std::string, size_t> index;
  for (const Record& r : records) {
    if (!r.valid) continue;
    const std::string k = key(r);
    if (!index.count(k)) {
      index[k] = series.size();
      series.push_back({k, {}, {}, {}, true});
    }
    PlotSeries& s = series[index[k]];
    s.x.push_back(x(r));
    s.y.push_back(y(r));
  }
  return series;
}

// Sorts each series' points by x (so polylines run left to right), keeping highlights aligned.
void SortByX(std::vector<PlotSeries>* series) {
  for (PlotSeries& s : *series) {
    std::vector<size_t> order(s.x.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return s.x[a] < s.x[b]; });
    PlotSeries sorted{s.name, {}, {}, {}, s.lines, s.connect_highlights};
    for (size_t i : order) {
      sorted.x.push_back(s.x[i]);
      sorted.y.push_back(s.y[i]);
      if (!s.highlight.empty()) sorted.highlight.push_back(s.highlight[i]);
    }
    s = sorted;
  }
}

double SpeedError(const SpeedErrorRecord& r) {
  return std::max(r.accuracy.median_rel_error_rho_d, r.accuracy.median_rel_error_n);
}

std::vector<NamedPlot> BuildPlots(const SuiteResults& r) {
  std::vector<NamedPlot> plots;
  auto backend = [](const auto& rec) { return rec.backend; };
  if (!r.fit.empty()) {
    NamedPlot p{"fit_speed.svg", "Fits per second against samples per texel, per backend (wall clock).", {}};
    p.plot.title = "Fit throughput";
    p.plot.x_label = "samples per texel";
    p.plot.y_label = "fits per second";
    p.plot.log_x = p.plot.log_y = true;
    p.plot.series = GroupSeries(r.fit, backend, [](const FitRecord& f) { return double(f.samples_per_texel); },
                                [](const FitRecord& f) { return f.fits_per_second; });
    plots.push_back(p);
  }
  if (!r.speed_vs_error.empty()) {
    NamedPlot p{"speed_vs_error.svg",
                "Speed against parameter error (max of the median relative errors of rho_d and n) "
                "over iteration caps and tolerances; ringed points, joined by a dashed line, are each "
                "backend's Pareto front.",
                {}};
    p.plot.title = "Speed against error";
    p.plot.x_label = "fits per second";
    p.plot.y_label = "median rel. error, max(rho_d, n)";
    p.plot.log_x = p.plot.log_y = true;
    p.plot.highlight_label = "Pareto front";
    std::map<std::string, size_t> index;
    for (const SpeedErrorRecord& s : r.speed_vs_error) {
      if (!s.valid) continue;
      if (!index.count(s.backend)) {
        index[s.backend] = p.plot.series.size();
        p.plot.series.push_back({s.backend, {}, {}, {}, false, true});
      }
      PlotSeries& series = p.plot.series[index[s.backend]];
      series.x.push_back(s.fits_per_second);
      series.y.push_back(SpeedError(s));
      series.highlight.push_back(s.pareto);
    }
    plots.push_back(p);
    NamedPlot q{"speed_vs_psnr.svg",
                "Speed against BRDF-space holdout PSNR (held-out directions) over the same points.",
                {}};
    q.plot.title = "Speed against holdout PSNR";
    q.plot.x_label = "fits per second";
    q.plot.y_label = "holdout PSNR, dB";
    q.plot.log_x = true;
    q.plot.series = GroupSeries(r.speed_vs_error, backend,
                                [](const SpeedErrorRecord& s) { return s.fits_per_second; },
                                [](const SpeedErrorRecord& s) { return s.accuracy.holdout_psnr_db; });
    for (PlotSeries& s : q.plot.series) s.lines = false;
    plots.push_back(q);
  }
  if (!r.init_schemes.empty()) {
    auto key = [](const InitRecord& i) { return i.backend + ", " + i.init; };
    auto samples = [](const InitRecord& i) { return double(i.samples_per_texel); };
    NamedPlot p{"init_converged.svg", "Converged fraction: seed start + two stages against fixed start + one stage.", {}};
    p.plot.title = "Initialisation: converged fraction";
    p.plot.x_label = "samples per texel";
    p.plot.y_label = "converged fraction";
    p.plot.log_x = true;
    p.plot.series = GroupSeries(r.init_schemes, key, samples,
                                [](const InitRecord& i) { return i.accuracy.converged_fraction; });
    plots.push_back(p);
    NamedPlot q{"init_error.svg", "Median relative error of n: seed against fixed start.", {}};
    q.plot.title = "Initialisation: error of n";
    q.plot.x_label = "samples per texel";
    q.plot.y_label = "median rel. error of n";
    q.plot.log_x = q.plot.log_y = true;
    q.plot.series = GroupSeries(r.init_schemes, key, samples,
                                [](const InitRecord& i) { return i.accuracy.median_rel_error_n; });
    plots.push_back(q);
    NamedPlot t{"init_speed.svg", "Fits per second: seed against fixed start (wall clock).", {}};
    t.plot.title = "Initialisation: speed";
    t.plot.x_label = "samples per texel";
    t.plot.y_label = "fits per second";
    t.plot.log_x = t.plot.log_y = true;
    t.plot.series = GroupSeries(r.init_schemes, key, samples,
                                [](const InitRecord& i) { return i.fits_per_second; });
    plots.push_back(t);
  }
  if (!r.scaling.empty()) {
    auto stage = [](const ScalingRecord& s) { return s.stage; };
    auto texels = [](const ScalingRecord& s) { return double(s.texels); };
    NamedPlot p{"scaling_time.svg", "Wall-clock time per pipeline stage against texel count.", {}};
    p.plot.title = "Scaling: time per stage";
    p.plot.x_label = "texels";
    p.plot.y_label = "seconds";
    p.plot.log_x = p.plot.log_y = true;
    p.plot.series = GroupSeries(r.scaling, stage, texels, [](const ScalingRecord& s) { return s.seconds; });
    plots.push_back(p);
    NamedPlot q{"scaling_memory.svg", StrCat("Peak resident memory per stage (", r.rss_method, ")."), {}};
    q.plot.title = "Scaling: peak resident memory per stage";
    q.plot.x_label = "texels";
    q.plot.y_label = "peak RSS, MiB";
    q.plot.log_x = q.plot.log_y = true;
    q.plot.series = GroupSeries(r.scaling, stage, texels,
                                [](const ScalingRecord& s) { return double(s.peak_rss_bytes) / (1 << 20); });
    plots.push_back(q);
  }
  if (!r.viewpoints.empty()) {
    NamedPlot p{"viewpoints.svg",
                "Holdout PSNR (re-rendered holdout photographs) against viewpoints = cameras x "
                "turntable steps, as in the seed paper's Figs. 20-21.",
                {}};
    p.plot.title = "Accuracy against viewpoints";
    p.plot.x_label = "viewpoints (cameras x turntable steps)";
    p.plot.y_label = "holdout PSNR, dB";
    const int cameras0 = r.viewpoints.front().cameras;
    int steps1 = -1;
    for (const ViewpointRecord& v : r.viewpoints) {
      if (v.cameras != cameras0) {
        steps1 = v.steps;
        break;
      }
    }
    PlotSeries by_steps{StrCat("steps vary (", cameras0, " cameras)"), {}, {}, {}, true};
    PlotSeries by_cameras{StrCat("cameras vary (", steps1, " steps)"), {}, {}, {}, true};
    for (const ViewpointRecord& v : r.viewpoints) {
      if (!v.valid) continue;
      if (v.cameras == cameras0) {
        by_steps.x.push_back(v.viewpoints);
        by_steps.y.push_back(v.holdout_psnr_db);
      }
      if (v.steps == steps1) {
        by_cameras.x.push_back(v.viewpoints);
        by_cameras.y.push_back(v.holdout_psnr_db);
      }
    }
    p.plot.series.push_back(by_steps);
    if (steps1 > 0) p.plot.series.push_back(by_cameras);
    plots.push_back(p);
  }
  for (NamedPlot& p : plots) SortByX(&p.plot.series);
  return plots;
}

std::string Html(const std::string& s) { return XmlEscape(s); }

// An HTML table of a JSON record list; invalid rows are marked.
std::string HtmlTable(const Json& list) {
  if (list.empty()) return "<p><em>no records</em></p>\n";
  std::ostringstream out;
  out << "<table>\n<tr>";
  for (auto it = list[0].begin(); it != list[0].end(); ++it) out << "<th>" << Html(it.key()) << "</th>";
  out << "</tr>\n";
  for (const Json& rec : list) {
    const bool valid = !rec.contains("valid") || rec["valid"].get<bool>();
    out << (valid ? "<tr>" : "<tr class=\"invalid\">");
    for (auto it = rec.begin(); it != rec.end(); ++it) {
      std::string text;
      if (it->is_number_float()) {
        // Rates and byte counts as whole numbers, small values to 4 significant digits.
        const double v = it->get<double>();
        std::ostringstream f;
        if (std::abs(v) >= 1000) {
          f << std::fixed;
          f.precision(0);
        } else {
          f.precision(4);
        }
        f << v;
        text = f.str();
      } else {
        text = it->is_string() ? it->get<std::string>() : it->dump();
      }
      out << "<td>" << Html(text) << "</td>";
    }
    out << "</tr>\n";
  }
  out << "</table>\n";
  return out.str();
}

std::string BuildIndex(const SuiteResults& r, const Json& j, const std::vector<NamedPlot>& plots) {
  std::ostringstream out;
  out << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>reflcap bench</title>\n"
      << "<style>body{font-family:sans-serif;margin:2em;max-width:1200px}"
         "table{border-collapse:collapse;font-size:12px;margin:0.5em 0 1.5em}"
         "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
         "tr.invalid td{background:#fdd}img{border:1px solid #eee;margin:0.5em 0}"
         "</style></head><body>\n"
      << "<h1>reflcap bench (" << Html(r.scale) << ")</h1>\n<table>\n"
      << "<tr><th>date</th><td>" << Html(r.date) << "</td></tr>\n"
      << "<tr><th>machine</th><td>" << Html(r.machine.ToString()) << "</td></tr>\n"
      << "<tr><th>device</th><td>" << Html(r.device) << "</td></tr>\n"
      << "<tr><th>device peaks</th><td>"
      << (r.device_mad_gflops > 0
              ? StrCat(std::lround(r.device_mad_gflops), " GFLOP/s multiply-add, ",
                       std::lround(r.device_copy_gbps), " GB/s device copy (measured)")
              : std::string("not measured"))
      << "</td></tr>\n"
      << "<tr><th>reflcap</th><td>" << Html(r.reflcap_version) << "</td></tr>\n"
      << "<tr><th>total time</th><td>" << std::lround(r.total_seconds) << " s</td></tr>\n";
  for (const OmittedBackend& o : r.omitted) {
    out << "<tr><th>omitted</th><td>" << Html(o.backend + ": " + o.reason) << "</td></tr>\n";
  }
  out << "</table>\n<p>Files: <a href=\"bench_results.json\">bench_results.json</a>";
  for (const std::string& sweep : AllSweeps()) {
    out << ", <a href=\"" << sweep << ".csv\">" << sweep << ".csv</a>";
  }
  out << ". Rows shaded red failed their verification against ground truth (reason in "
         "<code>invalid_reason</code>); their timings do not count and the plots leave them out. "
         "Field definitions: bench/README.md.</p>\n";
  const std::vector<std::pair<std::string, std::string>> sections = {
      {"fit", "1. Fits per second against samples per texel"},
      {"speed_vs_error", "2. Speed against error"},
      {"scaling", "3. Scaling with texel count: time and peak memory per stage"},
      {"init_schemes", "4. Seed two-stage start against fixed start"},
      {"viewpoints", "5. Accuracy against viewpoints"}};
  const std::map<std::string, std::vector<std::string>> section_plots = {
      {"fit", {"fit_speed.svg"}},
      {"speed_vs_error", {"speed_vs_error.svg", "speed_vs_psnr.svg"}},
      {"scaling", {"scaling_time.svg", "scaling_memory.svg"}},
      {"init_schemes", {"init_converged.svg", "init_error.svg", "init_speed.svg"}},
      {"viewpoints", {"viewpoints.svg"}}};
  for (const auto& [key, title] : sections) {
    out << "<h2>" << Html(title) << "</h2>\n";
    for (const NamedPlot& p : plots) {
      const auto& files = section_plots.at(key);
      if (std::find(files.begin(), files.end(), p.file) == files.end()) continue;
      out << "<p><a href=\"" << p.file << "\"><img src=\"" << p.file << "\" alt=\""
          << Html(p.plot.title) << "\"></a><br>" << Html(p.caption) << "</p>\n";
    }
    out << HtmlTable(j[key]);
  }
  if (!r.notes.empty()) {
    out << "<h2>Notes</h2>\n<ul>\n";
    for (const std::string& n : r.notes) out << "<li>" << Html(n) << "</li>\n";
    out << "</ul>\n";
  }
  out << "</body></html>\n";
  return out.str();
}

}  // namespace

std::string SuiteResultsJson(const SuiteResults& results) {
  return BuildJson(results).dump(2) + "\n";
}

Status WriteSuiteOutputs(const SuiteResults& results_in, const fs::path& dir) {
  SuiteResults results = results_in;
  const std::vector<NamedPlot> plots = BuildPlots(results);
  std::vector<std::pair<std::string, std::string>> svgs;
  for (const NamedPlot& p : plots) {
    PlotOutput o = RenderSvgPlot(p.plot);
    for (const std::string& n : o.notes) results.notes.push_back(p.file + ": " + n);
    svgs.emplace_back(p.file, std::move(o.svg));
  }
  int invalid = 0;
  for (const auto& r : results.fit) invalid += !r.valid;
  for (const auto& r : results.speed_vs_error) invalid += !r.valid;
  for (const auto& r : results.scaling) invalid += !r.valid;
  for (const auto& r : results.init_schemes) invalid += !r.valid;
  for (const auto& r : results.viewpoints) invalid += !r.valid;
  if (invalid > 0) {
    results.notes.push_back(StrCat(invalid, " records failed their verification (valid = false); the "
                                            "plots leave them out"));
  }
  const Json j = BuildJson(results);
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "bench_results.json", j.dump(2) + "\n"));
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "fit.csv", ToCsv(j["fit"], KeysOf<FitRecord>())));
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(
      dir / "speed_vs_error.csv", ToCsv(j["speed_vs_error"], KeysOf<SpeedErrorRecord>())));
  REFLCAP_RETURN_IF_ERROR(
      WriteTextFileAtomic(dir / "scaling.csv", ToCsv(j["scaling"], KeysOf<ScalingRecord>())));
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "init_schemes.csv",
                                              ToCsv(j["init_schemes"], KeysOf<InitRecord>())));
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "viewpoints.csv",
                                              ToCsv(j["viewpoints"], KeysOf<ViewpointRecord>())));
  for (const auto& [file, svg] : svgs) REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / file, svg));
  return WriteTextFileAtomic(dir / "index.html", BuildIndex(results, j, plots));
}

std::string SuiteSummaryText(const SuiteResults& r) {
  std::ostringstream out;
  out << "machine: " << r.machine.ToString() << "\n"
      << "device:  " << r.device << "\n";
  if (r.device_mad_gflops > 0) {
    out << "peaks:   " << std::lround(r.device_mad_gflops) << " GFLOP/s multiply-add, "
        << std::lround(r.device_copy_gbps) << " GB/s device copy\n";
  }
  for (const OmittedBackend& o : r.omitted) out << "omitted: " << o.backend << ": " << o.reason << "\n";
  auto round = [](double v) { return std::lround(v); };
  for (const FitRecord& f : r.fit) {
    if (f.samples_per_texel != 64) continue;
    out << "fit, 64 samples: " << f.backend << " " << round(f.fits_per_second) << " fits/s ("
        << round(f.fits_per_cpu_second) << " per CPU-s), converged "
        << std::round(f.accuracy.converged_fraction * 1000) / 10 << " %"
        << (f.gflops > 0 ? StrCat(", ", std::lround(f.gflops), " GFLOP/s = ",
                                  std::round(f.peak_fraction * 1000) / 10, " % of peak")
                         : std::string())
        << (f.valid ? "" : ", INVALID") << "\n";
  }
  std::map<std::string, int> pareto;
  for (const SpeedErrorRecord& s : r.speed_vs_error) pareto[s.backend] += s.pareto;
  for (const auto& [backend, n] : pareto) {
    out << "speed_vs_error: " << backend << ": " << n << " points on the Pareto front\n";
  }
  for (const InitRecord& i : r.init_schemes) {
    out << "init " << i.init << ", " << i.backend << ", " << i.samples_per_texel
        << " samples: converged " << std::round(i.accuracy.converged_fraction * 1000) / 10
        << " %, median rel. error n " << std::round(i.accuracy.median_rel_error_n * 1e4) / 100
        << " %, " << round(i.fits_per_second) << " fits/s\n";
  }
  if (!r.scaling.empty()) {
    const int64_t largest = r.scaling.back().texels;
    for (const ScalingRecord& s : r.scaling) {
      if (s.texels != largest) continue;
      out << "scaling, " << s.texels << " texels: " << s.stage << " "
          << std::round(s.seconds * 100) / 100 << " s, peak RSS " << (s.peak_rss_bytes >> 20)
          << " MiB" << (s.valid ? "" : ", INVALID") << "\n";
    }
  }
  for (const ViewpointRecord& v : r.viewpoints) {
    out << "viewpoints " << v.cameras << " x " << v.steps << ": holdout PSNR "
        << std::round(v.holdout_psnr_db * 100) / 100 << " dB" << (v.valid ? "" : ", INVALID") << "\n";
  }
  int invalid = 0;
  for (const auto& x : r.fit) invalid += !x.valid;
  for (const auto& x : r.speed_vs_error) invalid += !x.valid;
  for (const auto& x : r.scaling) invalid += !x.valid;
  for (const auto& x : r.init_schemes) invalid += !x.valid;
  for (const auto& x : r.viewpoints) invalid += !x.valid;
  out << "invalid records: " << invalid << "; total " << round(r.total_seconds) << " s\n";
  return out.str();
}

}  // namespace reflcap::benchsuite
