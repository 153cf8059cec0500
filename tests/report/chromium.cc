#include "tests/report/chromium.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <random>
#include <stdexcept>
#include <thread>

namespace slshadow::testing {
namespace fs = std::filesystem;
using nlohmann::json;

std::string DecodeBase64(const std::string& text) {
  std::string out;
  uint32_t acc = 0;
  int bits = 0;
  for (const char c : text) {
    int v = -1;
    if (c >= 'A' && c <= 'Z') v = c - 'A';
    if (c >= 'a' && c <= 'z') v = c - 'a' + 26;
    if (c >= '0' && c <= '9') v = c - '0' + 52;
    if (c == '+') v = 62;
    if (c == '/') v = 63;
    if (v < 0) continue;
    acc = (acc << 6) | static_cast<uint32_t>(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out += static_cast<char>((acc >> bits) & 0xff);
    }
  }
  return out;
}

HeadlessChromium::HeadlessChromium(int width, int height) {
  std::random_device rd;
  profile_ = fs::temp_directory_path() / ("slshadow-chromium-" + std::to_string(rd()));
  fs::create_directories(profile_);
  int in[2], out[2];
  if (pipe(in) != 0 || pipe(out) != 0) throw std::runtime_error("chromium: pipe failed");
  std::vector<std::string> args;
  const bool root = geteuid() == 0;
  if (root) args = {"unshare", "-n"};
  for (const char* a :
       {"chromium", "--headless", "--remote-debugging-pipe", "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader", "--no-first-run", "--no-default-browser-check",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--disable-extensions", "--disable-default-apps", "--mute-audio", "--hide-scrollbars",
        "--disable-features=Translate,MediaRouter,OptimizationHints,DialMediaRouteProvider",
        "--proxy-server=127.0.0.1:9", "--host-resolver-rules=MAP * ~NOTFOUND"})
    args.emplace_back(a);
  if (root) args.emplace_back("--no-sandbox");
  args.push_back("--user-data-dir=" + profile_.string());
  args.push_back("--window-size=" + std::to_string(width) + "," + std::to_string(height));
  args.emplace_back("about:blank");
  pid_ = fork();
  if (pid_ < 0) throw std::runtime_error("chromium: fork failed");
  if (pid_ == 0) {
    dup2(in[0], 3);
    dup2(out[1], 4);
    for (int fd : {in[0], in[1], out[0], out[1]}) {
      if (fd > 4) close(fd);
    }
    const int devnull = open("/dev/null", O_WRONLY);
    dup2(devnull, 1);
    dup2(devnull, 2);
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    execvp(argv[0], argv.data());
    _exit(127);
  }
  close(in[0]);
  close(out[1]);
  to_browser_ = in[1];
  from_browser_ = out[0];
  const json target = Call("Target.createTarget", {{"url", "about:blank"}}, false);
  const json attached = Call("Target.attachToTarget",
                             {{"targetId", target.at("targetId")}, {"flatten", true}}, false);
  session_ = attached.at("sessionId").get<std::string>();
  for (const char* domain : {"Runtime.enable", "Log.enable", "Network.enable", "Page.enable"})
    Call(domain);
  Call("Emulation.setDeviceMetricsOverride",
       {{"width", width}, {"height", height}, {"deviceScaleFactor", 1}, {"mobile", false}});
}

HeadlessChromium::~HeadlessChromium() {
  if (pid_ > 0) {
    try {
      json close = {{"id", next_id_++}, {"method", "Browser.close"}};
      const std::string text = close.dump() + std::string(1, '\0');
      (void)!write(to_browser_, text.data(), text.size());
    } catch (...) {}
    int status = 0;
    for (int i = 0; i < 100 && waitpid(pid_, &status, WNOHANG) == 0; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (waitpid(pid_, &status, WNOHANG) == 0) {
      kill(pid_, SIGKILL);
      waitpid(pid_, &status, 0);
    }
  }
  if (to_browser_ >= 0) close(to_browser_);
  if (from_browser_ >= 0) close(from_browser_);
  std::error_code ec;
  fs::remove_all(profile_, ec);
}

json HeadlessChromium::ReadMessage(double max_wait_s) {
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(max_wait_s * 1000));
  for (;;) {
    const size_t end = buffer_.find('\0');
    if (end != std::string::npos) {
      json message = json::parse(buffer_.substr(0, end));
      buffer_.erase(0, end + 1);
      return message;
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) throw std::runtime_error("chromium: no answer in time");
    pollfd p{from_browser_, POLLIN, 0};
    if (poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
    char chunk[1 << 16];
    const ssize_t n = read(from_browser_, chunk, sizeof(chunk));
    if (n <= 0) throw std::runtime_error("chromium: the browser closed its pipe (did it start?)");
    buffer_.append(chunk, static_cast<size_t>(n));
  }
}

json HeadlessChromium::Call(const std::string& method, const json& params, bool session) {
  const int id = next_id_++;
  json message = {{"id", id}, {"method", method}, {"params", params}};
  if (session) message["sessionId"] = session_;
  const std::string text = message.dump() + std::string(1, '\0');
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = write(to_browser_, text.data() + done, text.size() - done);
    if (n <= 0) throw std::runtime_error("chromium: cannot write to the browser");
    done += static_cast<size_t>(n);
  }
  for (;;) {
    const json reply = ReadMessage(180);
    if (reply.contains("id") && reply["id"] == id) {
      if (reply.contains("error"))
        throw std::runtime_error("chromium: " + method + ": " + reply["error"].dump());
      return reply.value("result", json::object());
    }
    Handle(reply);
  }
}

void HeadlessChromium::Handle(const json& event) {
  const std::string method = event.value("method", std::string());
  const json params = event.value("params", json::object());
  if (method == "Runtime.consoleAPICalled") {
    const std::string type = params.value("type", std::string());
    if (type == "error" || type == "assert") {
      std::string text = "console.";
      text += type;
      text += ':';
      for (const auto& a : params["args"])
        text.append(" ").append(a.contains("value") ? a["value"].dump()
                                                    : a.value("description", std::string()));
      problems_.push_back(text);
    }
  } else if (method == "Runtime.exceptionThrown") {
    const json& d = params["exceptionDetails"];
    problems_.push_back("exception: " + d.value("text", std::string()) + " " +
                        (d.contains("exception")
                             ? d["exception"].value("description", std::string())
                             : std::string()));
  } else if (method == "Log.entryAdded") {
    const json& e = params["entry"];
    if (e.value("level", std::string()) == "error")
      problems_.push_back("log: " + e.value("text", std::string()) + " " +
                          e.value("url", std::string()));
  } else if (method == "Network.requestWillBeSent") {
    const std::string url = params["request"].value("url", std::string());
    request_urls_[params.value("requestId", std::string())] = url;
    requests_.push_back(url.substr(0, 120));
    if (url.rfind("file:", 0) != 0 && url.rfind("data:", 0) != 0 && url.rfind("about:", 0) != 0)
      problems_.push_back("request to a non-local URL: " + url);
  } else if (method == "Network.loadingFailed") {
    problems_.push_back("request failed: " +
                        request_urls_[params.value("requestId", std::string())].substr(0, 200) +
                        ": " + params.value("errorText", std::string()));
  } else if (method == "Page.loadEventFired") {
    loaded_ = true;
  } else if (method == "Inspector.targetCrashed" || method == "Target.detachedFromTarget") {
    problems_.push_back("the page's target crashed or detached");
  }
}

void HeadlessChromium::ClearRecords() {
  problems_.clear();
  requests_.clear();
}

void HeadlessChromium::Navigate(const std::string& url) {
  loaded_ = false;
  const json r = Call("Page.navigate", {{"url", url}});
  if (r.contains("errorText")) problems_.push_back("navigation failed: " + r["errorText"].dump());
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(180);
  while (!loaded_ && std::chrono::steady_clock::now() < deadline) Handle(ReadMessage(180));
  if (!loaded_) throw std::runtime_error("chromium: " + url + " did not load");
}

json HeadlessChromium::Evaluate(const std::string& expression) {
  const json r = Call("Runtime.evaluate", {{"expression", expression}, {"returnByValue", true}});
  if (r.contains("exceptionDetails"))
    throw std::runtime_error("chromium: " + expression + ": " + r["exceptionDetails"].dump());
  return r["result"].value("value", json());
}

bool HeadlessChromium::WaitUntil(const std::string& expression, double max_wait_s) {
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(max_wait_s * 1000));
  while (std::chrono::steady_clock::now() < deadline) {
    if (Evaluate("!!(" + expression + ")") == true) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

std::string HeadlessChromium::Screenshot(double x, double y, double width, double height) {
  const json r =
      Call("Page.captureScreenshot",
           {{"format", "png"},
            {"clip", {{"x", x}, {"y", y}, {"width", width}, {"height", height}, {"scale", 1}}}});
  return DecodeBase64(r.at("data").get<std::string>());
}

void HeadlessChromium::Drag(double x0, double y0, double x1, double y1, int steps, bool right) {
  const std::string button = right ? "right" : "left";
  const int buttons = right ? 2 : 1;
  Call("Input.dispatchMouseEvent", {{"type", "mouseMoved"}, {"x", x0}, {"y", y0}});
  Call("Input.dispatchMouseEvent", {{"type", "mousePressed"},
                                    {"x", x0},
                                    {"y", y0},
                                    {"button", button},
                                    {"buttons", buttons},
                                    {"clickCount", 1}});
  for (int i = 1; i <= steps; ++i) {
    const double t = static_cast<double>(i) / steps;
    Call("Input.dispatchMouseEvent", {{"type", "mouseMoved"},
                                      {"x", x0 + t * (x1 - x0)},
                                      {"y", y0 + t * (y1 - y0)},
                                      {"button", button},
                                      {"buttons", buttons}});
  }
  Call("Input.dispatchMouseEvent", {{"type", "mouseReleased"},
                                    {"x", x1},
                                    {"y", y1},
                                    {"button", button},
                                    {"buttons", 0},
                                    {"clickCount", 1}});
}

void HeadlessChromium::Click(double x, double y) {
  Call("Input.dispatchMouseEvent", {{"type", "mouseMoved"}, {"x", x}, {"y", y}});
  Call("Input.dispatchMouseEvent", {{"type", "mousePressed"},
                                    {"x", x},
                                    {"y", y},
                                    {"button", "left"},
                                    {"buttons", 1},
                                    {"clickCount", 1}});
  Call("Input.dispatchMouseEvent", {{"type", "mouseReleased"},
                                    {"x", x},
                                    {"y", y},
                                    {"button", "left"},
                                    {"buttons", 0},
                                    {"clickCount", 1}});
}

}  // namespace slshadow::testing
