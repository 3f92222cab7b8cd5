#include "engine/core/status.h"

#include <gtest/gtest.h>

namespace reflcap {
namespace {

StatusOr<int> Half(int x) {
  if (x % 2) return InvalidArgumentError("value ", x, " is odd");
  return x / 2;
}

Status Quarter(int x, int* out) {
  REFLCAP_ASSIGN_OR_RETURN(int half, Half(x));
  REFLCAP_ASSIGN_OR_RETURN(*out, Half(half));
  return OkStatus();
}

TEST(Status, PropagatesFirstErrorWithMessage) {
  int out = 0;
  EXPECT_TRUE(Quarter(8, &out).ok());
  EXPECT_EQ(out, 2);
  Status s = Quarter(6, &out);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(s.message(), "value 3 is odd");
  EXPECT_EQ(s.WithContext("f.json").ToString(), "InvalidArgument: f.json: value 3 is odd");
}

TEST(Status, ExitCodesSeparateBadInputFromBackendAndBugs) {
  EXPECT_EQ(ExitCodeFor(OkStatus()), 0);
  EXPECT_EQ(ExitCodeFor(NotFoundError("x")), 2);
  EXPECT_EQ(ExitCodeFor(DataLossError("x")), 2);
  EXPECT_EQ(ExitCodeFor(UnavailableError("x")), 3);
  EXPECT_EQ(ExitCodeFor(InternalError("x")), 4);
}

}  // namespace
}  // namespace reflcap
