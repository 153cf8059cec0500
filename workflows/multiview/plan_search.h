// The set cover behind `slshadow plan` (plan.h): which few candidate views together reconstruct
// the target share of the part's reachable surface. A candidate is the set of surface samples it
// reconstructs; the samples that exactly the same candidates reconstruct are merged into one
// weighted class first (the search then runs over classes, not samples).
//
// FewestCover: greedy (the candidate adding the most, until `needed` samples are covered), then,
// for one view fewer at a time, a swap search (one pick exchanged for another while the union
// grows, from the greedy's picks and the caller's seeds) and, when that does not reach `needed`, a
// branch and bound over the subsets of that size (MaxCoverage) which either finds one or proves
// that none exists (when it ends within its budget). Of the sets of the size found, the one the
// swap search from it and from the seeds of that size finds covering the most.
//
// MaxCoverage: depth-first over the subsets in increasing index order, the children by their gain;
// a branch is cut when its covered samples plus the sum of the largest gains still to pick (or
// plus all the samples the candidates left can still reach, whichever is less) cannot beat the
// best subset found. Exhaustive within the budget: then its subset covers the most of any.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace slshadow::multiview {

class CoverInstance {
 public:
  // sets[c][i] != 0: candidate c covers element i; all of the same length (the elements).
  explicit CoverInstance(const std::vector<const std::vector<uint8_t>*>& sets);

  size_t Candidates() const { return n_; }
  size_t Elements() const { return elements_; }
  size_t Classes() const { return weights_.size(); }
  // How many elements the union of `picks` covers.
  size_t Covered(const std::vector<size_t>& picks) const;

 private:
  friend class CoverSearch;
  friend std::vector<size_t> GreedyCover(const CoverInstance& instance, size_t needed);
  friend std::vector<size_t> SwapSearch(const CoverInstance& instance, std::vector<size_t> start);
  // Sum of the weights of the classes set in a & ~b (b may be null: all of a).
  size_t WeightAndNot(const uint64_t* a, const uint64_t* b) const;
  size_t n_ = 0, elements_ = 0, words_ = 0;
  std::vector<size_t> weights_;             // per class, ascending
  std::vector<uint32_t> word_weight_;       // per word of classes: its classes' weight, 0 if mixed
  std::vector<std::vector<uint64_t>> set_;  // per candidate, its classes as bits
  // reachable_from_[k]: the classes some candidate >= k covers (k = 0 .. n).
  std::vector<std::vector<uint64_t>> reachable_from_;
};

struct CoverSearchOptions {
  // Budget of MaxCoverage, in gain evaluations (one candidate against a union, over all classes);
  // past it the search stops and its result is not exact.
  uint64_t max_evaluations = 200'000'000;
};

// The best subset of one size found by a search.
struct SubsetSearch {
  std::vector<size_t> picks;  // increasing candidate indices
  size_t covered = 0;
  bool exact = false;        // exhaustive: no subset of this size covers more
  uint64_t evaluations = 0;  // gain evaluations spent
};

// The most elements any `m` candidates cover, by branch and bound from `incumbent` (m picks, may
// be empty); stops early (not exact) once a subset covers `stop_at` or the budget is spent.
SubsetSearch MaxCoverage(const CoverInstance& instance, size_t m, size_t stop_at,
                         const std::vector<size_t>& incumbent,
                         const CoverSearchOptions& options = {});

// Greedy picks until `needed` are covered or nothing more is gained (in the order picked).
std::vector<size_t> GreedyCover(const CoverInstance& instance, size_t needed);

// From `start`: while exchanging one pick for a candidate not picked grows the union, the best
// such exchange. Never covers fewer than `start`.
std::vector<size_t> SwapSearch(const CoverInstance& instance, std::vector<size_t> start);

struct CoverPlan {
  std::vector<size_t> picks;  // the fewest found reaching `needed` (greedy's when none does)
  size_t covered = 0;
  bool reached = false;
  std::vector<size_t> greedy;  // greedy's picks, in its order
  size_t greedy_covered = 0;
  // The best subset of one pick fewer than `picks` found; exact: the search was exhaustive, so
  // no subset of that size reaches `needed` (the plan is the fewest possible).
  SubsetSearch one_fewer;
  uint64_t evaluations = 0;
};

// The fewest candidates covering `needed` elements. `seeds`: further starting subsets for the swap
// search (any sizes; those of the size tried are used), e.g. evenly spaced table angles.
CoverPlan FewestCover(const CoverInstance& instance, size_t needed,
                      const std::vector<std::vector<size_t>>& seeds = {},
                      const CoverSearchOptions& options = {});

}  // namespace slshadow::multiview
