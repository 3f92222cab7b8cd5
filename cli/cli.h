#pragma once
// Command-line plumbing shared by the `reflcap` verbs: a small declarative option parser with
// generated --help, and the exit-code convention.
//
// Exit codes: 0 success; 1 command-line usage error; 2 bad input (a missing, malformed or
// inconsistent file or field); 3 a requested backend is unavailable; 4 internal error.
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "engine/core/status.h"

namespace reflcap::cli {

constexpr int kExitUsage = 1;

class ArgParser {
 public:
  ArgParser(std::string verb, std::string synopsis, std::string description);

  void AddFlag(const std::string& name, bool* value, const std::string& help);
  void AddString(const std::string& name, std::string* value, const std::string& metavar,
                 const std::string& help);
  void AddInt(const std::string& name, int* value, const std::string& help);
  void AddInt64(const std::string& name, int64_t* value, const std::string& help);
  void AddUint64(const std::string& name, uint64_t* value, const std::string& help);
  void AddDouble(const std::string& name, double* value, const std::string& help);
  // Positional arguments, in order.
  void AddPositional(const std::string& name, std::string* value, const std::string& help);
  // One or more trailing positional arguments (after those of AddPositional), e.g. PARTS...
  void AddPositionalList(const std::string& name, std::vector<std::string>* values,
                         const std::string& help);

  // Parses argv[first..argc). Returns InvalidArgument for unknown options, missing values or
  // positionals, and malformed numbers. Sets *help when --help/-h was given (nothing else checked).
  Status Parse(int argc, char** argv, int first, bool* help);
  std::string Help() const;

 private:
  struct Option {
    std::string name, metavar, help;
    bool is_flag = false;
    std::function<Status(const std::string&)> set;
  };
  struct Positional {
    std::string name, help;
    std::string* value;
  };
  std::string verb_, synopsis_, description_;
  std::vector<Option> options_;
  std::vector<Positional> positionals_;
  std::string list_name_, list_help_;
  std::vector<std::string>* list_ = nullptr;
};

// The last line a shard run prints on stdout, for batch systems' logs: "reflcap-shard-summary "
// and one JSON object {"stage", "shard": "I/N", "part" (absolute path), "seconds", then
// `numbers` (name -> value)}.
void PrintShardSummary(const std::string& stage, int index, int count, const std::string& part,
                       double seconds, const std::vector<std::pair<std::string, double>>& numbers);

// Prints `status` as "reflcap <verb>: <message>" on stderr and returns its exit code.
int ReportError(const std::string& verb, const Status& status);

// Applies the global options (--quiet anywhere: warnings and errors only) and removes them from
// argv; returns the new argc. Every executable's main calls it before the verb parses.
int TakeGlobalOptions(int argc, char** argv);

// Verbs.
int RunInfo(int argc, char** argv);
int RunSynth(int argc, char** argv);
int RunDemo(int argc, char** argv);
int RunResample(int argc, char** argv);  // verb_resample.cc
int RunFit(int argc, char** argv);       // verb_fit.cc
int RunRender(int argc, char** argv);    // verb_render.cc
int RunValidate(int argc, char** argv);  // verb_validate.cc
int RunImportDiligent(int argc, char** argv);  // verb_import_diligent.cc
int RunRun(int argc, char** argv);       // verb_run.cc
int RunBench(int argc, char** argv);     // verb_bench.cc
int RunCalibrate(int argc, char** argv); // verb_calibrate.cc
int RunHdr(int argc, char** argv);       // verb_hdr.cc
int RunScan(int argc, char** argv);      // verb_scan.cc
int RunMerge(int argc, char** argv);     // verb_merge.cc
int RunExport(int argc, char** argv);    // verb_export.cc
int RunView(int argc, char** argv);      // verb_view.cc


}  // namespace reflcap::cli
