// The plan's set cover (workflows/multiview/plan_search.h) against a brute force over every subset
// of small instances: the branch and bound finds the optimum the brute force finds, the fewest
// cover is the brute force's fewest, and the swap search is never worse than greedy.
#include "workflows/multiview/plan_search.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <random>
#include <vector>

#include "core/error.h"

namespace slshadow::multiview {
namespace {

using Sets = std::vector<std::vector<uint8_t>>;

std::vector<const std::vector<uint8_t>*> Pointers(const Sets& sets) {
  std::vector<const std::vector<uint8_t>*> p;
  for (const auto& s : sets) p.push_back(&s);
  return p;
}

// Candidates like table angles: each element is seen from an arc of candidates (a random start
// and length, wrapping round), some from two arcs, a few from none; fixed seed.
Sets ArcInstance(size_t candidates, size_t elements, unsigned seed) {
  std::mt19937 rng(seed);
  Sets sets(candidates, std::vector<uint8_t>(elements, 0));
  std::uniform_int_distribution<size_t> start(0, candidates - 1), len(1, candidates / 2);
  std::uniform_real_distribution<double> u(0, 1);
  for (size_t i = 0; i < elements; ++i) {
    const int arcs = u(rng) < 0.05 ? 0 : (u(rng) < 0.3 ? 2 : 1);
    for (int a = 0; a < arcs; ++a) {
      const size_t s = start(rng), l = len(rng);
      for (size_t k = 0; k < l; ++k) sets[(s + k) % candidates][i] = 1;
    }
  }
  return sets;
}

// Every subset of the candidates as a mask: the elements its union covers.
std::vector<size_t> BruteForceCovered(const Sets& sets) {
  const size_t n = sets.size(), ne = sets[0].size();
  std::vector<size_t> covered(size_t{1} << n, 0);
  for (size_t mask = 1; mask < covered.size(); ++mask) {
    size_t hit = 0;
    for (size_t i = 0; i < ne; ++i) {
      bool any = false;
      for (size_t c = 0; c < n && !any; ++c) any = (mask >> c & 1) && sets[c][i];
      hit += any;
    }
    covered[mask] = hit;
  }
  return covered;
}

TEST(PlanSearchTest, ClassesCountTheElementsAsTheSetsDo) {
  const Sets sets = ArcInstance(9, 400, 7);
  const CoverInstance instance(Pointers(sets));
  EXPECT_EQ(instance.Candidates(), 9u);
  EXPECT_EQ(instance.Elements(), 400u);
  EXPECT_LT(instance.Classes(), 400u);  // merged: arcs repeat
  const std::vector<size_t> covered = BruteForceCovered(sets);
  for (size_t mask = 1; mask < covered.size(); mask += 7) {
    std::vector<size_t> picks;
    for (size_t c = 0; c < 9; ++c)
      if (mask >> c & 1) picks.push_back(c);
    EXPECT_EQ(instance.Covered(picks), covered[mask]) << mask;
  }
  const Sets bad = {std::vector<uint8_t>(3, 1), std::vector<uint8_t>(4, 1)};
  EXPECT_THROW(CoverInstance{Pointers(bad)}, Error);
}

TEST(PlanSearchTest, BranchAndBoundFindsTheBruteForceOptimum) {
  for (unsigned seed = 1; seed <= 12; ++seed) {
    const size_t n = 8 + seed % 5;  // 8 .. 12 candidates
    const Sets sets = ArcInstance(n, 300, seed);
    const CoverInstance instance(Pointers(sets));
    const std::vector<size_t> covered = BruteForceCovered(sets);
    for (size_t m = 1; m <= 5; ++m) {
      size_t best = 0;
      for (size_t mask = 1; mask < covered.size(); ++mask)
        if (static_cast<size_t>(std::popcount(mask)) == m) best = std::max(best, covered[mask]);
      // From nothing and from greedy's picks; never stopped early (stop_at past every element).
      for (const bool seeded : {false, true}) {
        std::vector<size_t> start;
        if (seeded) {
          start = GreedyCover(instance, sets[0].size());
          start.resize(std::min(start.size(), m));
          if (start.size() != m) start.clear();
        }
        const SubsetSearch found = MaxCoverage(instance, m, sets[0].size() + 1, start);
        EXPECT_TRUE(found.exact) << "seed " << seed << " m " << m;
        EXPECT_EQ(found.covered, best) << "seed " << seed << " m " << m;
        ASSERT_EQ(found.picks.size(), m);
        EXPECT_EQ(instance.Covered(found.picks), best);
      }
    }
  }
}

TEST(PlanSearchTest, FewestCoverIsTheBruteForceFewestAndNeverWorseThanGreedy) {
  size_t greedy_worse = 0;
  for (unsigned seed = 20; seed < 40; ++seed) {
    const size_t n = 10;
    const Sets sets = ArcInstance(n, 250, seed);
    const CoverInstance instance(Pointers(sets));
    const std::vector<size_t> covered = BruteForceCovered(sets);
    const size_t reachable = covered.back();
    for (const double target : {0.9, 0.95, 0.98, 1.0}) {
      const auto needed = static_cast<size_t>(std::ceil(target * static_cast<double>(reachable)));
      size_t fewest = n + 1, best_fewer = 0;
      for (size_t mask = 1; mask < covered.size(); ++mask) {
        if (covered[mask] >= needed)
          fewest = std::min(fewest, static_cast<size_t>(std::popcount(mask)));
      }
      for (size_t mask = 1; mask < covered.size(); ++mask)
        if (static_cast<size_t>(std::popcount(mask)) == fewest - 1)
          best_fewer = std::max(best_fewer, covered[mask]);
      const CoverPlan plan = FewestCover(instance, needed);
      ASSERT_TRUE(plan.reached);
      EXPECT_EQ(plan.picks.size(), fewest) << "seed " << seed << " target " << target;
      EXPECT_GE(plan.covered, needed);
      EXPECT_EQ(instance.Covered(plan.picks), plan.covered);
      EXPECT_LE(plan.picks.size(), plan.greedy.size());
      // Never covers less than greedy's as many picks.
      EXPECT_GE(plan.covered,
                instance.Covered(std::vector<size_t>(
                    plan.greedy.begin(),
                    plan.greedy.begin() + static_cast<std::ptrdiff_t>(plan.picks.size()))));
      greedy_worse += plan.greedy.size() > plan.picks.size();
      if (fewest > 1) {
        EXPECT_TRUE(plan.one_fewer.exact);
        EXPECT_EQ(plan.one_fewer.covered, best_fewer) << "seed " << seed << " target " << target;
      }
      // The swap search from greedy's first k picks never covers fewer than they do.
      for (size_t k = 1; k <= plan.greedy.size(); ++k) {
        const std::vector<size_t> prefix(plan.greedy.begin(),
                                         plan.greedy.begin() + static_cast<std::ptrdiff_t>(k));
        const std::vector<size_t> swapped = SwapSearch(instance, prefix);
        ASSERT_EQ(swapped.size(), k);
        EXPECT_GE(instance.Covered(swapped), instance.Covered(prefix));
      }
    }
  }
  // The search is more than greedy on these instances: somewhere greedy needed a view more.
  EXPECT_GT(greedy_worse, 0u);
}

// The textbook case where greedy needs a set more than the optimum: two rows of 7 elements
// (weights 1, 2, 4 per row: 2 x (1+2+4) = 14) and columns of 2, 4 and 8 elements. Greedy takes
// the 8 column first and needs all three columns; the two rows cover everything.
TEST(PlanSearchTest, GreedysTrapIsAvoided) {
  // Elements 0..13: row A = 0..6, row B = 7..13; column c1 = {0, 7}, c2 = {1, 2, 8, 9},
  // c3 = {3..6, 10..13}.
  Sets sets(5, std::vector<uint8_t>(14, 0));
  for (size_t i = 0; i < 7; ++i) sets[0][i] = sets[1][7 + i] = 1;
  for (size_t i : {0, 7}) sets[2][i] = 1;
  for (size_t i : {1, 2, 8, 9}) sets[3][i] = 1;
  for (size_t i : {3, 4, 5, 6, 10, 11, 12, 13}) sets[4][i] = 1;
  const CoverInstance instance(Pointers(sets));
  const CoverPlan plan = FewestCover(instance, 14);
  EXPECT_EQ(plan.greedy.size(), 3u);
  EXPECT_EQ(plan.greedy.front(), 4u);
  EXPECT_EQ(plan.picks, (std::vector<size_t>{0, 1}));
  EXPECT_TRUE(plan.one_fewer.exact);
  EXPECT_EQ(plan.one_fewer.covered, 8u);
}

TEST(PlanSearchTest, ABudgetTooSmallIsNotExact) {
  const Sets sets = ArcInstance(12, 300, 3);
  const CoverInstance instance(Pointers(sets));
  CoverSearchOptions tiny;
  tiny.max_evaluations = 5;
  const SubsetSearch found = MaxCoverage(instance, 4, 301, {}, tiny);
  EXPECT_FALSE(found.exact);
  const SubsetSearch full = MaxCoverage(instance, 4, 301, {});
  EXPECT_TRUE(full.exact);
  EXPECT_LE(found.covered, full.covered);
}

}  // namespace
}  // namespace slshadow::multiview
