// Time to interactive of a report page in headless Chromium (offline, SwiftShader WebGL, as the
// tests run it): each run starts a fresh browser, loads the page from file:// and reads
// performance.now() at the moment the page's view is first drawn (window.slshadow.timings,
// milliseconds since navigation start). Prints each run and the median.
//   build/bench/report/page_bench out/demo/report.html [runs=5]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "tests/report/chromium.h"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s PAGE.html [runs]\n", argv[0]);
    return 2;
  }
  const std::filesystem::path page = std::filesystem::absolute(argv[1]);
  const int runs = argc > 2 ? std::atoi(argv[2]) : 5;
  std::vector<double> ready, decoded, start;
  for (int r = 0; r < runs; ++r) {
    slshadow::testing::HeadlessChromium browser;
    browser.Navigate("file://" + page.string());
    if (!browser.WaitUntil("window.slshadow && window.slshadow.ready", 300)) {
      std::fprintf(stderr, "run %d: the page did not become ready\n", r);
      return 1;
    }
    for (const auto& p : browser.problems()) std::fprintf(stderr, "problem: %s\n", p.c_str());
    ready.push_back(browser.Evaluate("window.slshadow.timings.ready_ms").get<double>());
    start.push_back(browser.Evaluate("window.slshadow.timings.start_ms").get<double>());
    decoded.push_back(browser.Evaluate("window.slshadow.timings.built_ms").get<double>());
    std::printf(
        "run %d: page parsed (viewer script starts) at %.0f ms, first cloud decoded and "
        "built at %.0f ms, interactive (view drawn) at %.0f ms\n",
        r, start.back(), decoded.back(), ready.back());
  }
  const auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[(v.size() - 1) / 2];
  };
  std::printf(
      "%s: %.1f MB; median of %d runs: parsed %.0f ms, built %.0f ms, interactive %.0f ms\n",
      page.string().c_str(), static_cast<double>(std::filesystem::file_size(page)) / 1e6, runs,
      median(start), median(decoded), median(ready));
  return 0;
}
