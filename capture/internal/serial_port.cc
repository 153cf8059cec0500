#include "capture/internal/serial_port.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "capture/turntable.h"

namespace slshadow::capture::internal {
namespace {

speed_t SpeedOf(int baud) {
  switch (baud) {
    case 9600:
      return B9600;
    case 19200:
      return B19200;
    case 38400:
      return B38400;
    case 57600:
      return B57600;
    case 115200:
      return B115200;
    case 230400:
      return B230400;
    case 460800:
      return B460800;
    case 500000:
      return B500000;
    case 921600:
      return B921600;
    case 1000000:
      return B1000000;
    default:
      return B0;
  }
}

// Milliseconds from now to `deadline`, rounded up, at least 0.
int MsUntil(SerialPort::Clock::time_point deadline) {
  const auto left = deadline - SerialPort::Clock::now();
  if (left <= SerialPort::Clock::duration::zero()) return 0;
  return static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(left).count());
}

}  // namespace

SerialPort::SerialPort(const std::string& path, int baud) : path_(path) {
  const speed_t speed = SpeedOf(baud);
  if (speed == B0) {
    throw TurntableError(TurntableFault::kRefused,
                         "baud " + std::to_string(baud) +
                             " is not a serial speed slshadow sets (9600, 19200, 38400, 57600, "
                             "115200, 230400, 460800, 500000, 921600, 1000000)");
  }
  fd_ = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) {
    const int e = errno;
    throw TurntableError(TurntableFault::kDisconnected,
                         "cannot open " + path + ": " + std::strerror(e) +
                             (e == EBUSY ? " (another program holds the port)" : ""));
  }
  termios tio{};
  if (!::isatty(fd_) || ::tcgetattr(fd_, &tio) != 0) {
    ::close(fd_);
    throw TurntableError(TurntableFault::kRefused,
                         path + " is not a serial port (not a terminal device)");
  }
  // Exclusive use keeps a second program off the port; a port that refuses it still works.
  (void)::ioctl(fd_, TIOCEXCL);
  ::cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~static_cast<tcflag_t>(CSTOPB | CRTSCTS);
  tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  if (::cfsetispeed(&tio, speed) != 0 || ::cfsetospeed(&tio, speed) != 0 ||
      ::tcsetattr(fd_, TCSANOW, &tio) != 0) {
    const int e = errno;
    ::close(fd_);
    throw TurntableError(
        TurntableFault::kRefused,
        "cannot set " + path + " to raw " + std::to_string(baud) + " baud: " + std::strerror(e));
  }
  ::tcflush(fd_, TCIOFLUSH);
}

SerialPort::~SerialPort() {
  if (fd_ < 0) return;
  (void)::ioctl(fd_, TIOCNXCL);  // the next program (or this one, reopening) may open it
  ::close(fd_);
}

void SerialPort::Vanished(const std::string& what) const {
  throw TurntableError(TurntableFault::kDisconnected,
                       "the port " + path_ + " vanished (" + what + ")");
}

void SerialPort::Write(const std::string& bytes, Clock::time_point deadline) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd_, bytes.data() + done, bytes.size() - done);
    if (n > 0) {
      done += static_cast<size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && errno != EAGAIN) Vanished(std::string("write: ") + std::strerror(errno));
    pollfd p{fd_, POLLOUT, 0};
    const int ready = ::poll(&p, 1, MsUntil(deadline));
    if (ready < 0 && errno != EINTR) Vanished(std::string("poll: ") + std::strerror(errno));
    if (ready == 0) {
      throw TurntableError(TurntableFault::kTimeout, "the port " + path_ + " takes no more output");
    }
    if (p.revents & (POLLHUP | POLLERR | POLLNVAL)) Vanished("hang-up");
  }
}

std::optional<std::string> SerialPort::ReadLine(Clock::time_point deadline) {
  for (;;) {
    for (;;) {
      const size_t end = buffer_.find_first_of("\r\n");
      if (end == std::string::npos) break;
      std::string line = buffer_.substr(0, end);
      buffer_.erase(0, end + 1);
      if (!line.empty()) return line;
    }
    pollfd p{fd_, POLLIN, 0};
    const int ready = ::poll(&p, 1, MsUntil(deadline));
    if (ready < 0) {
      if (errno == EINTR) continue;
      Vanished(std::string("poll: ") + std::strerror(errno));
    }
    if (ready == 0) return std::nullopt;
    if (p.revents & POLLIN) {
      char chunk[256];
      const ssize_t n = ::read(fd_, chunk, sizeof chunk);
      if (n > 0) {
        buffer_.append(chunk, static_cast<size_t>(n));
        continue;
      }
      if (n == 0) Vanished("end of file");
      if (errno == EAGAIN || errno == EINTR) continue;
      Vanished(std::string("read: ") + std::strerror(errno));
    }
    if (p.revents & (POLLHUP | POLLERR | POLLNVAL)) Vanished("hang-up");
  }
}

void SerialPort::DiscardInput() {
  ::tcflush(fd_, TCIFLUSH);
  buffer_.clear();
}

}  // namespace slshadow::capture::internal
