// Debian's chromium, headless, driven over the DevTools protocol on --remote-debugging-pipe
// (fd 3: commands in, fd 4: replies and events out, messages NUL-separated). Started as root
// inside a fresh network namespace (`unshare -n`: only a loopback that is down), with every host
// name unresolvable and a dead proxy, so no page can send anything off the machine; every request
// the page makes is recorded and any that is not file:, data: or about: counts as a problem.
//
// Problems recorded while a page runs: console.error / console.assert, uncaught exceptions,
// Log domain errors (e.g. CSP violations, failed resource loads), failed requests, requests to
// anything but file: / data: / about: URLs, a crashed or detached target.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace slshadow::testing {

class HeadlessChromium {
 public:
  // Starts the browser with a page `width` x `height` CSS px (device scale 1). Throws
  // std::runtime_error when chromium cannot be started or does not answer.
  explicit HeadlessChromium(int width = 1280, int height = 900);
  ~HeadlessChromium();
  HeadlessChromium(const HeadlessChromium&) = delete;
  HeadlessChromium& operator=(const HeadlessChromium&) = delete;

  // Loads `url` and waits for its load event.
  void Navigate(const std::string& url);
  // Evaluates a JavaScript expression in the page; returns its value (by value). Throws on an
  // exception in the page.
  nlohmann::json Evaluate(const std::string& expression);
  // Evaluates `expression` until it is true; false when `max_wait_s` passes first (a guard
  // against a hang, not a measurement).
  bool WaitUntil(const std::string& expression, double max_wait_s = 120);
  // PNG of the page area (CSS px).
  std::string Screenshot(double x, double y, double width, double height);
  // Mouse: press at (x0, y0), move in `steps` to (x1, y1), release (left button; right when
  // `right`).
  void Drag(double x0, double y0, double x1, double y1, int steps = 10, bool right = false);
  void Click(double x, double y);

  const std::vector<std::string>& problems() const { return problems_; }
  const std::vector<std::string>& requests() const { return requests_; }
  void ClearRecords();

 private:
  nlohmann::json Call(const std::string& method,
                      const nlohmann::json& params = nlohmann::json::object(), bool session = true);
  nlohmann::json ReadMessage(double max_wait_s);
  void Handle(const nlohmann::json& event);

  pid_t pid_ = -1;
  int to_browser_ = -1, from_browser_ = -1;
  std::string buffer_;
  int next_id_ = 1;
  std::string session_;
  bool loaded_ = false;
  std::filesystem::path profile_;
  std::vector<std::string> problems_, requests_;
  std::map<std::string, std::string> request_urls_;
};

// Base64 decoding (DevTools sends screenshots as base64).
std::string DecodeBase64(const std::string& text);

}  // namespace slshadow::testing
