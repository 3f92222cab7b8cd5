#include "engine/core/atomic_file.h"

#include <gtest/gtest.h>

#include "engine/core/html.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

TEST(WriteFileAtomic, FailedWriterLeavesPreviousFileAndNoTemporary) {
  testing::ScratchDir dir;
  const fs::path target = dir / "out.txt";
  ASSERT_TRUE(WriteTextFileAtomic(target, "first").ok());
  Status s = WriteFileAtomic(target, [](const fs::path& tmp) {
    testing::WriteText(tmp, "partial");
    return InternalError("simulated failure");
  });
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(*ReadTextFile(target), "first");
  int entries = 0;
  for (const auto& e : fs::directory_iterator(dir.path())) entries += e.exists();
  EXPECT_EQ(entries, 1) << "the temporary file must be removed";
}

TEST(StagingDir, UncommittedOutputVanishesAndCommitMovesIntoPlace) {
  testing::ScratchDir dir;
  const fs::path dest = dir / "result";
  {
    auto staging = StagingDir::Create(dest, false);
    ASSERT_TRUE(staging.ok());
    testing::WriteText(staging->path() / "a.txt", "x");
  }
  EXPECT_FALSE(fs::exists(dest));
  auto staging = StagingDir::Create(dest, false);
  ASSERT_TRUE(staging.ok());
  testing::WriteText(staging->path() / "a.txt", "x");
  ASSERT_TRUE(staging->Commit().ok());
  EXPECT_TRUE(fs::exists(dest / "a.txt"));
}

TEST(StagingDir, ReportsNameTheFinalFolderAfterCommit) {
  testing::ScratchDir dir;
  // A destination whose name needs escaping in JSON and HTML.
  const fs::path dest = dir / "run \"a&b\"";
  auto staging = StagingDir::Create(dest, false);
  ASSERT_TRUE(staging.ok());
  const std::string raw = staging->path().string();
  std::string json = raw;  // as nlohmann::json writes it inside a string
  for (size_t at = json.find('"'); at != std::string::npos; at = json.find('"', at + 2)) json.insert(at, "\\");
  testing::WriteText(staging->path() / "fit/fit_report.json", "{\"samples\": \"" + json + "/samples\"}\n");
  testing::WriteText(staging->path() / "report/report.html",
                     "<p>" + HtmlEscape(raw + "/renders") + "</p>");
  testing::WriteText(staging->path() / "notes.txt", raw);  // neither JSON nor HTML: untouched
  ASSERT_TRUE(staging->NameFinalPaths().ok());
  ASSERT_TRUE(staging->Commit().ok());
  const std::string report = ReadTextFile(dest / "fit/fit_report.json").value();
  EXPECT_EQ(report.find(raw), std::string::npos) << report;
  EXPECT_NE(report.find("run \\\"a&b\\\"/samples"), std::string::npos) << report;
  const std::string html = ReadTextFile(dest / "report/report.html").value();
  EXPECT_NE(html.find(HtmlEscape(dest.string() + "/renders")), std::string::npos) << html;
  EXPECT_EQ(ReadTextFile(dest / "notes.txt").value(), raw);
}

TEST(StagingDir, RefusesNonEmptyDestinationUnlessOverwrite) {
  testing::ScratchDir dir;
  const fs::path dest = dir / "result";
  testing::WriteText(dest / "user_file.txt", "precious");
  auto refused = StagingDir::Create(dest, false);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("not empty"), std::string::npos);
  EXPECT_TRUE(fs::exists(dest / "user_file.txt"));
  auto staging = StagingDir::Create(dest, true);
  ASSERT_TRUE(staging.ok());
  testing::WriteText(staging->path() / "new.txt", "y");
  ASSERT_TRUE(staging->Commit().ok());
  EXPECT_TRUE(fs::exists(dest / "new.txt"));
  EXPECT_FALSE(fs::exists(dest / "user_file.txt"));
}

}  // namespace
}  // namespace reflcap
