#include <gtest/gtest.h>
TEST(Commands, Exist) {}
