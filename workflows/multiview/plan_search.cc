#include "workflows/multiview/plan_search.h"

#include <algorithm>
#include <bit>
#include <functional>
#include <map>
#include <numeric>

#include "core/error.h"

namespace slshadow::multiview {

using Words = std::vector<uint64_t>;

CoverInstance::CoverInstance(const std::vector<const std::vector<uint8_t>*>& sets)
    : n_(sets.size()) {
  SLSHADOW_THROW_IF(sets.empty(), "plan: no candidate views");
  elements_ = sets[0]->size();
  for (const auto* s : sets)
    SLSHADOW_THROW_IF(s->size() != elements_, "plan: candidates over different samples");
  // The classes: elements covered by exactly the same candidates (by their candidates' bits).
  const size_t sig_words = (n_ + 63) / 64;
  std::map<Words, size_t> count;
  Words sig(sig_words);
  for (size_t i = 0; i < elements_; ++i) {
    std::fill(sig.begin(), sig.end(), 0);
    for (size_t c = 0; c < n_; ++c)
      if ((*sets[c])[i]) sig[c / 64] |= uint64_t{1} << (c % 64);
    ++count[sig];
  }
  std::vector<std::pair<size_t, const Words*>> classes;  // weight, signature
  for (const auto& [s, w] : count) {
    if (std::all_of(s.begin(), s.end(), [](uint64_t x) { return x == 0; })) continue;  // none
    classes.emplace_back(w, &s);
  }
  std::stable_sort(classes.begin(), classes.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  words_ = (classes.size() + 63) / 64;
  set_.assign(n_, Words(words_, 0));
  weights_.resize(classes.size());
  std::vector<size_t> last(classes.size(), 0);  // the last candidate covering each class
  for (size_t k = 0; k < classes.size(); ++k) {
    weights_[k] = classes[k].first;
    const Words& s = *classes[k].second;
    for (size_t c = 0; c < n_; ++c) {
      if (s[c / 64] >> (c % 64) & 1) {
        set_[c][k / 64] |= uint64_t{1} << (k % 64);
        last[k] = c;
      }
    }
  }
  word_weight_.assign(words_, 0);
  for (size_t w = 0; w < words_; ++w) {
    const size_t lo = w * 64, hi = std::min(weights_.size(), lo + 64);
    if (weights_[lo] == weights_[hi - 1]) word_weight_[w] = static_cast<uint32_t>(weights_[lo]);
  }
  reachable_from_.assign(n_ + 1, Words(words_, 0));
  for (size_t k = 0; k < classes.size(); ++k)
    for (size_t from = 0; from <= last[k]; ++from)
      reachable_from_[from][k / 64] |= uint64_t{1} << (k % 64);
}

size_t CoverInstance::WeightAndNot(const uint64_t* a, const uint64_t* b) const {
  size_t sum = 0;
  for (size_t w = 0; w < words_; ++w) {
    uint64_t x = b ? a[w] & ~b[w] : a[w];
    if (!x) continue;
    if (word_weight_[w]) {
      sum += word_weight_[w] * static_cast<size_t>(std::popcount(x));
      continue;
    }
    while (x) {
      sum += weights_[w * 64 + static_cast<size_t>(std::countr_zero(x))];
      x &= x - 1;
    }
  }
  return sum;
}

size_t CoverInstance::Covered(const std::vector<size_t>& picks) const {
  Words u(words_, 0);
  for (size_t c : picks) {
    SLSHADOW_THROW_IF(c >= n_, "plan: candidate ", c, " of ", n_);
    for (size_t w = 0; w < words_; ++w) u[w] |= set_[c][w];
  }
  return WeightAndNot(u.data(), nullptr);
}

class CoverSearch {
 public:
  CoverSearch(const CoverInstance& in, size_t m, size_t stop_at, uint64_t budget)
      : in_(in), m_(m), stop_at_(stop_at), budget_(budget), unions_(m + 1, Words(in.words_, 0)) {}

  SubsetSearch Run(const std::vector<size_t>& incumbent) {
    if (incumbent.size() == m_) {
      best_.picks = incumbent;
      std::sort(best_.picks.begin(), best_.picks.end());
      best_.covered = in_.Covered(incumbent);
    }
    if (m_ == 0 || m_ > in_.n_ || best_.covered >= stop_at_) {
      best_.exact = m_ == 0 || m_ > in_.n_;
      return best_;
    }
    picks_.resize(m_);
    Dfs(0, 0, 0);
    best_.exact = !stopped_;
    best_.evaluations = evaluations_;
    return best_;
  }

 private:
  // unions_[d]: the union of the first d picks, covering `covered`; candidates from `first` on.
  void Dfs(size_t d, size_t covered, size_t first) {
    const size_t r = m_ - d, n = in_.n_;
    const uint64_t* u = unions_[d].data();
    std::vector<std::pair<size_t, size_t>> gains;  // gain, candidate
    for (size_t c = first; c < n; ++c)
      gains.emplace_back(in_.WeightAndNot(in_.set_[c].data(), u), c);
    evaluations_ += gains.size();
    if (gains.empty()) return;
    if (r == 1) {
      const auto it =
          std::max_element(gains.begin(), gains.end(),
                           [](const auto& a, const auto& b) { return a.first < b.first; });
      if (covered + it->first > best_.covered) {
        picks_[d] = it->second;
        best_.picks = picks_;
        best_.covered = covered + it->first;
        if (best_.covered >= stop_at_) stopped_ = true;
      }
      return;
    }
    // Bound: the r largest gains from `first` on, or all the classes still reachable.
    std::vector<size_t> g;
    for (const auto& x : gains) g.push_back(x.first);
    std::partial_sort(g.begin(), g.begin() + static_cast<std::ptrdiff_t>(std::min(r, g.size())),
                      g.end(), std::greater<>());
    const size_t top = std::accumulate(
        g.begin(), g.begin() + static_cast<std::ptrdiff_t>(std::min(r, g.size())), size_t{0});
    const size_t left = in_.WeightAndNot(in_.reachable_from_[first].data(), u);
    if (covered + std::min(top, left) <= best_.covered) return;
    // The children, the largest gain first; each child's bound from the gains after it.
    std::vector<std::pair<size_t, size_t>> order = gains;
    std::stable_sort(order.begin(), order.end(),
                     [](const auto& a, const auto& b) { return a.first > b.first; });
    for (const auto& [gain, c] : order) {
      if (c + r > n) continue;  // too few candidates after c for the other picks
      if (stopped_) return;
      if (evaluations_ > budget_) {
        stopped_ = true;
        return;
      }
      // Upper bound of the child: its gain plus the r - 1 largest gains after c.
      std::vector<size_t> after;
      for (const auto& x : gains)
        if (x.second > c) after.push_back(x.first);
      const size_t k = std::min(r - 1, after.size());
      std::partial_sort(after.begin(), after.begin() + static_cast<std::ptrdiff_t>(k), after.end(),
                        std::greater<>());
      const size_t rest =
          std::accumulate(after.begin(), after.begin() + static_cast<std::ptrdiff_t>(k), size_t{0});
      if (covered + gain + rest <= best_.covered) continue;
      picks_[d] = c;
      const uint64_t* s = in_.set_[c].data();
      uint64_t* next = unions_[d + 1].data();
      for (size_t w = 0; w < in_.words_; ++w) next[w] = u[w] | s[w];
      Dfs(d + 1, covered + gain, c + 1);
    }
  }

  const CoverInstance& in_;
  const size_t m_, stop_at_;
  const uint64_t budget_;
  std::vector<Words> unions_;
  std::vector<size_t> picks_;
  SubsetSearch best_;
  uint64_t evaluations_ = 0;
  bool stopped_ = false;
};

SubsetSearch MaxCoverage(const CoverInstance& instance, size_t m, size_t stop_at,
                         const std::vector<size_t>& incumbent, const CoverSearchOptions& options) {
  return CoverSearch(instance, m, stop_at, options.max_evaluations).Run(incumbent);
}

std::vector<size_t> GreedyCover(const CoverInstance& in, size_t needed) {
  Words u(in.words_, 0);
  std::vector<size_t> picks;
  std::vector<bool> used(in.n_, false);
  size_t covered = 0;
  while (covered < needed) {
    size_t best = in.n_, best_gain = 0;
    for (size_t c = 0; c < in.n_; ++c) {
      if (used[c]) continue;
      const size_t gain = in.WeightAndNot(in.set_[c].data(), u.data());
      if (gain > best_gain) best = c, best_gain = gain;
    }
    if (best == in.n_) break;
    used[best] = true;
    for (size_t w = 0; w < in.words_; ++w) u[w] |= in.set_[best][w];
    covered += best_gain;
    picks.push_back(best);
  }
  return picks;
}

std::vector<size_t> SwapSearch(const CoverInstance& in, std::vector<size_t> start) {
  if (start.empty()) return start;
  size_t covered = in.Covered(start);
  while (true) {
    size_t best_i = 0, best_c = in.n_, best_covered = covered;
    std::vector<bool> picked(in.n_, false);
    for (size_t c : start) picked[c] = true;
    for (size_t i = 0; i < start.size(); ++i) {
      Words others(in.words_, 0);  // the union of the picks but the i-th
      for (size_t j = 0; j < start.size(); ++j)
        if (j != i)
          for (size_t w = 0; w < in.words_; ++w) others[w] |= in.set_[start[j]][w];
      const size_t base = in.WeightAndNot(others.data(), nullptr);
      for (size_t c = 0; c < in.n_; ++c) {
        if (picked[c]) continue;
        const size_t total = base + in.WeightAndNot(in.set_[c].data(), others.data());
        if (total > best_covered) best_i = i, best_c = c, best_covered = total;
      }
    }
    if (best_c == in.n_) return start;
    start[best_i] = best_c;
    covered = best_covered;
  }
}

CoverPlan FewestCover(const CoverInstance& in, size_t needed,
                      const std::vector<std::vector<size_t>>& seeds,
                      const CoverSearchOptions& options) {
  CoverPlan plan;
  plan.greedy = GreedyCover(in, needed);
  plan.greedy_covered = in.Covered(plan.greedy);
  plan.picks = plan.greedy;
  plan.covered = plan.greedy_covered;
  plan.reached = plan.covered >= needed;
  if (!plan.reached) return plan;
  while (plan.picks.size() > 1) {
    const size_t m = plan.picks.size() - 1;
    // The swap search from greedy's first m picks and from each seed of size m.
    std::vector<std::vector<size_t>> starts = {std::vector<size_t>(
        plan.greedy.begin(),
        plan.greedy.begin() + static_cast<std::ptrdiff_t>(std::min(m, plan.greedy.size())))};
    for (const auto& s : seeds)
      if (s.size() == m) starts.push_back(s);
    std::vector<size_t> best;
    size_t best_covered = 0;
    for (const auto& s : starts) {
      if (s.size() != m) continue;
      std::vector<size_t> local = SwapSearch(in, s);
      const size_t covered = in.Covered(local);
      if (best.empty() || covered > best_covered) best = std::move(local), best_covered = covered;
    }
    if (best_covered < needed) {
      plan.one_fewer = MaxCoverage(in, m, needed, best, options);
      plan.evaluations += plan.one_fewer.evaluations;
      if (plan.one_fewer.covered < needed) break;
      best = plan.one_fewer.picks;
      best_covered = plan.one_fewer.covered;
    }
    plan.one_fewer = {};
    plan.picks = best;
    plan.covered = best_covered;
  }
  if (plan.picks.size() == 1 && plan.one_fewer.picks.empty()) plan.one_fewer.exact = true;
  // Of the sets of that size, the one covering the most that the swap search finds from the plan
  // and the seeds of its size: a margin over the target.
  std::vector<std::vector<size_t>> starts = {plan.picks};
  for (const auto& s : seeds)
    if (s.size() == plan.picks.size()) starts.push_back(s);
  for (const auto& s : starts) {
    std::vector<size_t> local = SwapSearch(in, s);
    const size_t covered = in.Covered(local);
    if (covered > plan.covered) plan.picks = std::move(local), plan.covered = covered;
  }
  return plan;
}

}  // namespace slshadow::multiview
