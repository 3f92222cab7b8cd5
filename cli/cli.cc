#include "cli/cli.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>

#include <nlohmann/json.hpp>

#include "engine/core/log.h"

namespace reflcap::cli {
namespace {

template <typename T>
Status ParseNumber(const std::string& name, const std::string& text, T* out) {
  const char* begin = text.data();
  const char* end = begin + text.size();
  if constexpr (std::is_floating_point_v<T>) {
    char* stop = nullptr;
    const double v = std::strtod(text.c_str(), &stop);
    if (text.empty() || stop != text.c_str() + text.size() || !std::isfinite(v)) {
      return InvalidArgumentError("--", name, ": \"", text, "\" is not a finite number");
    }
    *out = T(v);
  } else {
    auto [ptr, ec] = std::from_chars(begin, end, *out);
    if (ec != std::errc() || ptr != end) {
      return InvalidArgumentError("--", name, ": \"", text, "\" is not an integer in range");
    }
  }
  return OkStatus();
}

}  // namespace

ArgParser::ArgParser(std::string verb, std::string synopsis, std::string description)
    : verb_(std::move(verb)), synopsis_(std::move(synopsis)), description_(std::move(description)) {}

void ArgParser::AddFlag(const std::string& name, bool* value, const std::string& help) {
  options_.push_back({name, "", help, true, [value](const std::string&) {
                        *value = true;
                        return OkStatus();
                      }});
}

void ArgParser::AddString(const std::string& name, std::string* value, const std::string& metavar,
                          const std::string& help) {
  options_.push_back({name, metavar, help, false, [value](const std::string& v) {
                        *value = v;
                        return OkStatus();
                      }});
}

#define REFLCAP_NUMERIC_OPTION(Method, Type, Metavar)                                    \
  void ArgParser::Method(const std::string& name, Type* value, const std::string& help) { \
    options_.push_back({name, Metavar, help, false, [name, value](const std::string& v) { \
                          return ParseNumber(name, v, value);                              \
                        }});                                                               \
  }
REFLCAP_NUMERIC_OPTION(AddInt, int, "N")
REFLCAP_NUMERIC_OPTION(AddInt64, int64_t, "N")
REFLCAP_NUMERIC_OPTION(AddUint64, uint64_t, "N")
REFLCAP_NUMERIC_OPTION(AddDouble, double, "X")
#undef REFLCAP_NUMERIC_OPTION

void ArgParser::AddPositional(const std::string& name, std::string* value, const std::string& help) {
  positionals_.push_back({name, help, value});
}

void ArgParser::AddPositionalList(const std::string& name, std::vector<std::string>* values,
                                  const std::string& help) {
  list_name_ = name;
  list_help_ = help;
  list_ = values;
}

Status ArgParser::Parse(int argc, char** argv, int first, bool* help) {
  *help = false;
  for (int i = first; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      *help = true;
      return OkStatus();
    }
  }
  size_t next_positional = 0;
  for (int i = first; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg.size() > 2 && arg.compare(0, 2, "--") == 0) {
      std::string name = arg.substr(2), inline_value;
      const bool has_inline = name.find('=') != std::string::npos;
      if (has_inline) {
        inline_value = name.substr(name.find('=') + 1);
        name = name.substr(0, name.find('='));
      }
      const Option* option = nullptr;
      for (const auto& o : options_) {
        if (o.name == name) option = &o;
      }
      if (!option) return InvalidArgumentError("unknown option --", name, " (see reflcap ", verb_, " --help)");
      if (option->is_flag) {
        if (has_inline) return InvalidArgumentError("--", name, " takes no value");
        REFLCAP_RETURN_IF_ERROR(option->set(""));
        continue;
      }
      if (!has_inline) {
        if (i + 1 >= argc) return InvalidArgumentError("--", name, " needs a value");
        inline_value = argv[++i];
      }
      REFLCAP_RETURN_IF_ERROR(option->set(inline_value));
      continue;
    }
    if (next_positional >= positionals_.size()) {
      if (list_ == nullptr) {
        return InvalidArgumentError("unexpected argument \"", arg, "\" (see reflcap ", verb_, " --help)");
      }
      list_->push_back(arg);
      continue;
    }
    *positionals_[next_positional++].value = arg;
  }
  if (next_positional < positionals_.size()) {
    return InvalidArgumentError("missing ", positionals_[next_positional].name, " (see reflcap ",
                                verb_, " --help)");
  }
  if (list_ != nullptr && list_->empty()) {
    return InvalidArgumentError("missing ", list_name_, " (see reflcap ", verb_, " --help)");
  }
  return OkStatus();
}

std::string ArgParser::Help() const {
  std::ostringstream out;
  out << "usage: reflcap " << verb_ << " " << synopsis_ << "\n\n" << description_ << "\n";
  if (!positionals_.empty() || list_ != nullptr) {
    out << "\narguments:\n";
    for (const auto& p : positionals_) {
      char line[64];
      std::snprintf(line, sizeof line, "  %-22s ", p.name.c_str());
      out << line << p.help << "\n";
    }
    if (list_ != nullptr) {
      char line[64];
      std::snprintf(line, sizeof line, "  %-22s ", (list_name_ + "...").c_str());
      out << line << list_help_ << "\n";
    }
  }
  out << "\noptions:\n";
  for (const auto& o : options_) {
    const std::string head = "--" + o.name + (o.metavar.empty() ? "" : " " + o.metavar);
    char line[64];
    std::snprintf(line, sizeof line, "  %-22s ", head.c_str());
    out << line << o.help << "\n";
  }
  out << "  --quiet                only warnings and errors on stderr\n"
         "  --help                 this text\n"
         "\nexit codes: 0 ok, 1 usage error, 2 bad input, 3 backend unavailable, 4 internal error\n";
  return out.str();
}

void PrintShardSummary(const std::string& stage, int index, int count, const std::string& part,
                       double seconds, const std::vector<std::pair<std::string, double>>& numbers) {
  std::error_code ec;
  const std::filesystem::path absolute = std::filesystem::absolute(part, ec);
  nlohmann::json summary = {{"stage", stage},
                            {"shard", std::to_string(index) + "/" + std::to_string(count)},
                            {"part", (ec ? std::filesystem::path(part) : absolute.lexically_normal()).string()},
                            {"seconds", seconds}};
  for (const auto& [name, value] : numbers) summary[name] = value;
  std::printf("reflcap-shard-summary %s\n", summary.dump().c_str());
}

int ReportError(const std::string& verb, const Status& status) {
  std::fprintf(stderr, "reflcap %s: %s\n", verb.c_str(), status.message().c_str());
  return ExitCodeFor(status);
}

int TakeGlobalOptions(int argc, char** argv) {
  int kept = 1;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quiet") == 0) {
      SetLogThreshold(LogLevel::kWarning);
    } else {
      argv[kept++] = argv[i];
    }
  }
  return kept;
}

}  // namespace reflcap::cli
