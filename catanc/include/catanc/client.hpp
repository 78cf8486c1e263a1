// catanc/client.hpp: the C++ client of `catanc run` (protocol catanc/2), header-only.
//
// C++17, the standard library and POSIX (Linux) only.  Build with the flags that
// `catanc client --cflags` prints:
//
//     g++ -std=c++17 $(catanc client --cflags) -pthread my_node.cpp
//
// A node thread registers under its DAG node name, waits for a trigger, runs once, and says so:
//
//     #include <catanc/client.hpp>
//
//     catanc::Node node("LM");               // registers this thread; the socket from $CATANC_SOCKET
//     while (auto trigger = node.wait()) {   // empty once the enforcer stops (or interrupt())
//       step();                              // trigger->threads: threads this run may use
//       node.done();                         // records the run (this thread's CPU time since the
//     }                                      // trigger) and wakes the subchain's next node
//
// The enforcer pins and prioritises the registered thread, so construct the Node in the thread
// that does the work, and call wait() and done() from it.  `done(compute_ms)` reports a time the
// node measured itself (a run spread over trigger->threads threads: its wall time).  `begin()`
// then `done()` reports a run nothing triggered (a subscription callback later in a subchain).
// `done(catanc::Origin{stamp_ns})` (or `done(compute_ms, catanc::Origin{...})`) also reports when
// the data the run carries was sensed, in CLOCK_REALTIME ns (a ROS header.stamp): the enforcer
// logs each run's age (its end minus its origin).
// `interrupt()` ends the loop from another thread or a signal handler (it is async-signal-safe).
// Errors (no enforcer, a rejected registration) are catanc::Error, a std::runtime_error whose
// what() gives the reason the enforcer gave.  If the enforcer goes away without stopping the
// node (it was killed), wait() returns empty after one line on stderr, and lost() says why.
//
// Without an enforcer: `catanc::Node node("LM", 20.0)` runs the same loop on its own timer every
// 20 ms when $CATANC_SOCKET is unset (after one warning on stderr), so one binary works with and
// without catanc.  Without a fallback period that is an error.
//
// rclcpp
// ------
// The simplest pattern is a trigger thread: a std::thread that owns the catanc::Node and does the
// node's periodic work itself, in place of a wall timer.  Subscriptions keep running in the
// executor and hand their latest data over under a mutex; rclcpp publishers may be called from
// any thread.
//
//     class LocalMapper : public rclcpp::Node {
//      public:
//       LocalMapper() : rclcpp::Node("local_mapper") {
//         pub_ = create_publisher<nav_msgs::msg::OccupancyGrid>("map", 10);
//         worker_ = std::thread([this] {
//           try {
//             catanc::Node node("LM", 50.0);    // registers this thread; its own 50 ms timer without catanc
//             {
//               std::lock_guard<std::mutex> lock(mutex_);
//               node_ = &node;
//               if (stopping_) node.interrupt();
//             }
//             while (auto trigger = node.wait()) {
//               pub_->publish(update_map());    // the work, in the thread the enforcer schedules
//               node.done();
//             }
//             std::lock_guard<std::mutex> lock(mutex_);
//             node_ = nullptr;
//           } catch (const catanc::Error& error) {
//             RCLCPP_ERROR(get_logger(), "%s", error.what());
//           }
//         });
//       }
//       ~LocalMapper() override {
//         {
//           std::lock_guard<std::mutex> lock(mutex_);
//           stopping_ = true;
//           if (node_ != nullptr) node_->interrupt();
//         }
//         worker_.join();
//       }
//      private:
//       std::mutex mutex_;
//       bool stopping_ = false;
//       catanc::Node* node_ = nullptr;
//       std::thread worker_;
//       ...
//     };
//
// To run the work in the executor instead (a single-threaded executor whose callbacks must not
// race), construct the Node in the thread that calls spin(), before spinning, and let a small
// waker thread poll node.fd() (readable when a datagram waits) and trigger a guard condition
// that wakes the executor (rclcpp::GuardCondition with a Waitable, or a subscription to an
// intra-process topic the waker publishes to); its callback, in the registered thread, runs
// `while (auto trigger = node.wait(0.0)) { step(); node.done(); }`, which takes every trigger
// that has arrived and returns at once.  The waker waits for that callback before it polls again.
//
// The protocol is documented in catanc.runtime.protocol.messages (Python) for clients in any language.

#ifndef CATANC_CLIENT_HPP
#define CATANC_CLIENT_HPP

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <poll.h>
#include <sched.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

namespace catanc {

// What catanc.runtime.protocol.messages and catanc.runtime.protocol.ring say (a test checks they agree).
inline constexpr const char* kProtocol = "catanc/2";
inline constexpr const char* kSocketEnv = "CATANC_SOCKET";
inline constexpr std::size_t kMaxDatagram = 512;
inline constexpr std::size_t kMaxName = 128;
inline constexpr std::uint32_t kRingMagic = 0x52544143;
inline constexpr std::uint32_t kRingVersion = 1;
inline constexpr std::size_t kRingHeaderSize = 64;
inline constexpr std::size_t kRingEntrySize = 48;
inline constexpr std::size_t kRingWrittenOffset = 16;
inline constexpr std::uint64_t kUnknownCompute = ~std::uint64_t{0};

// A node cannot register with its enforcer, was rejected, or is used wrongly; what() says why.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Run once: run `seq` of the node's subchain, on `threads` threads.
struct Trigger {
  std::string node;
  std::uint64_t seq = 0;
  unsigned threads = 1;
};

// When the data a run carries was sensed: CLOCK_REALTIME ns, the clock of a ROS header.stamp
// (0 or less: none).
struct Origin {
  std::int64_t realtime_ns = 0;
};

namespace detail {

inline std::int64_t now_ns(clockid_t clock) {
  timespec ts{};
  ::clock_gettime(clock, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000 + ts.tv_nsec;
}

// An origin as the ring's CLOCK_MONOTONIC ns (0: none).
inline std::uint64_t monotonic_origin(Origin origin) {
  if (origin.realtime_ns <= 0) return 0;
  const std::int64_t monotonic = origin.realtime_ns - now_ns(CLOCK_REALTIME) + now_ns(CLOCK_MONOTONIC);
  return static_cast<std::uint64_t>(monotonic > 0 ? monotonic : 1);
}

inline bool valid_name(const std::string& name) {
  if (name.empty() || name.size() > kMaxName) return false;
  for (std::size_t i = 0; i < name.size(); ++i) {
    const char c = name[i];
    const bool letter = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || c == '_';
    if (!letter && !(i > 0 && c >= '0' && c <= '9')) return false;
  }
  return true;
}

inline std::vector<std::string> words(const char* data, std::size_t size) {
  std::vector<std::string> found;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= size; ++i) {
    if (i == size || data[i] == ' ') {
      found.emplace_back(data + start, i - start);
      start = i + 1;
    }
  }
  return found;
}

inline std::optional<std::uint64_t> number(const std::string& word) {
  if (word.empty() || word.size() > 19) return std::nullopt;
  std::uint64_t value = 0;
  for (char c : word) {
    if (c < '0' || c > '9') return std::nullopt;
    value = value * 10 + static_cast<std::uint64_t>(c - '0');
  }
  return value;
}

// An address as the protocol writes it (hex of the sun_path bytes, "-" for none); false if malformed.
inline bool parse_address(const std::string& word, std::string& address) {
  address.clear();
  if (word == "-") return true;
  if (word.empty() || word.size() % 2 != 0 || word.size() > 2 * sizeof(sockaddr_un::sun_path)) return false;
  auto digit = [](char c) -> int {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
  };
  for (std::size_t i = 0; i < word.size(); i += 2) {
    const int high = digit(word[i]), low = digit(word[i + 1]);
    if (high < 0 || low < 0) return false;
    address.push_back(static_cast<char>(high * 16 + low));
  }
  return true;
}

// sun_path bytes of a received sender; a path's trailing NULs dropped (an abstract address keeps them).
inline std::string sender_address(const sockaddr_un& from, socklen_t length) {
  const auto offset = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path));
  if (length <= offset) return {};
  std::string address(from.sun_path, static_cast<std::size_t>(length - offset));
  if (!address.empty() && address[0] != '\0') {
    while (!address.empty() && address.back() == '\0') address.pop_back();
  }
  return address;
}

// A socket address from sun_path bytes; its length, 0 if it does not fit.
inline socklen_t make_address(const std::string& path, sockaddr_un& to) {
  std::memset(&to, 0, sizeof to);
  to.sun_family = AF_UNIX;
  if (path.empty() || path.size() > sizeof to.sun_path) return 0;
  std::memcpy(to.sun_path, path.data(), path.size());
  return static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + path.size());
}

}  // namespace detail

// Tags a Node that runs on its input (a subscription callback later in a subchain): it reports
// each run with begin() and done(), no node sends it triggers, and without $CATANC_SOCKET it just
// runs, unreported (no fallback period, no warning).
struct OnInput {};

// One DAG node's trigger loop, run by the thread that constructs it.
class Node {
 public:
  // Registers the calling thread as node `name` with the enforcer at $CATANC_SOCKET (waiting up to
  // 5 s for its welcome).  Where $CATANC_SOCKET is unset and `fallback_period_ms` > 0, the node
  // runs on its own timer at that period instead; where it is unset and there is no fallback, or
  // the enforcer cannot be reached or rejects the node, this throws catanc::Error.
  explicit Node(std::string name, double fallback_period_ms = 0.0) : Node(std::move(name), fallback_period_ms, false) {}

  // Registers the calling thread as node `name`, which runs on its input: `catanc::Node node("LP",
  // catanc::OnInput{});` then `node.begin(); ...; node.done(catanc::Origin{stamp_ns});` per message.
  Node(std::string name, OnInput) : Node(std::move(name), 0.0, true) {}

 private:
  Node(std::string name, double fallback_period_ms, bool on_input) : name_(std::move(name)), on_input_(on_input) {
    if (!detail::valid_name(name_)) {
      throw Error("bad node name '" + name_ + "': an identifier of 1 to 128 characters");
    }
    if (!(fallback_period_ms >= 0.0) || !std::isfinite(fallback_period_ms)) {
      throw Error("node '" + name_ + "': the fallback period is a number of ms > 0 (or 0: none)");
    }
    wake_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (wake_ < 0) throw Error("node '" + name_ + "': eventfd: " + std::strerror(errno));
    tid_ = static_cast<long>(::syscall(SYS_gettid));
    thread_ = std::this_thread::get_id();
    const char* path = std::getenv(kSocketEnv);
    if (path == nullptr || *path == '\0') {
      if (on_input_) {
        standalone_ = true;  // no enforcer to report to: its runs are its own
        return;
      }
      if (fallback_period_ms <= 0.0) {
        ::close(wake_);
        throw Error(std::string("no catanc enforcer socket: ") + kSocketEnv +
                    " is not set (`catanc run` sets it for the nodes it starts); give the Node a fallback period "
                    "to run on its own timer");
      }
      period_ns_ = static_cast<std::int64_t>(fallback_period_ms * 1e6);
      if (period_ns_ < 1) period_ns_ = 1;
      next_tick_ns_ = detail::now_ns(CLOCK_MONOTONIC);
      std::fprintf(stderr, "catanc: %s is not set: node '%s' runs on its own timer every %g ms (no enforcer)\n",
                   kSocketEnv, name_.c_str(), fallback_period_ms);
      return;
    }
    socket_path_ = path;
    try {
      register_with_enforcer();
    } catch (...) {
      release();
      throw;
    }
  }

 public:

  Node(const Node&) = delete;
  Node& operator=(const Node&) = delete;

  // Leaves: says bye unless the enforcer ended the node, and releases the socket and the ring.
  ~Node() { release(); }

  // The next trigger; empty once the enforcer stopped the node, went away, or interrupt() was
  // called.  A pending run (a trigger without done()) is reported as done first.
  std::optional<Trigger> wait() { return wait_until(-1); }

  // The same, but empty also after `timeout_s` seconds (0: take what has arrived, do not block).
  std::optional<Trigger> wait(double timeout_s) {
    const double bounded = std::isfinite(timeout_s) && timeout_s > 0 ? std::min(timeout_s, 1e9) : 0.0;
    return wait_until(detail::now_ns(CLOCK_MONOTONIC) + static_cast<std::int64_t>(bounded * 1e9));
  }

  // Start a run nothing triggered (a subscription callback); report it with done().
  void begin() {
    check_thread("begin");
    start(Trigger{name_, 0, 1});
  }

  // Reports the current run, its compute time this thread's CPU time since the trigger, and wakes
  // the subchain's next node (on this CPU it runs before done() returns: this thread yields to it).
  void done() { finish(std::nullopt); }

  // Reports the current run with the compute time the node measured (ms; negative or not finite:
  // unknown).
  void done(double compute_ms) { finish(compute_ms); }

  // Reports the current run with its origin: when the data it carries was sensed (CLOCK_REALTIME).
  void done(Origin origin) { finish(std::nullopt, origin); }
  void done(double compute_ms, Origin origin) { finish(compute_ms, origin); }

  // Ends the loop: a blocked wait() returns empty.  Safe from any thread and from signal handlers
  // (an atomic store and a write(2)), while the Node exists.
  void interrupt() noexcept {
    interrupted_.store(true);
    const std::uint64_t one = 1;
    const ssize_t written = ::write(wake_, &one, sizeof one);  // EAGAIN: a wake-up is pending anyway
    (void)written;
  }

  const std::string& name() const { return name_; }
  long tid() const { return tid_; }
  bool registered() const { return registered_; }
  // True once the enforcer said stop or went away, or interrupt() was called.
  bool stopped() const { return ended_ || interrupted_.load(); }
  // True when the node runs on its own timer (no enforcer).
  bool on_fallback_timer() const { return period_ns_ > 0; }
  // Why the node lost its enforcer (it went away without a stop); empty if it did not.
  const std::string& lost() const { return lost_; }
  // The socket, readable when a datagram waits (for an executor's waker thread); -1 on the timer.
  int fd() const { return sock_; }

  // How long wait() blocks at most before it checks that the enforcer is still there.
  static constexpr int kProbeMs = 1000;
  static constexpr double kRegisterTimeoutS = 5.0;

 private:
  std::string name_;
  bool on_input_ = false;    // it runs on its input: its hello says so
  bool standalone_ = false;  // on its input without an enforcer
  std::string socket_path_;
  std::string enforcer_;  // the address the enforcer talks to this node from (the welcome's sender)
  std::string next_address_, next_node_, prev_address_;
  unsigned next_threads_ = 1;
  bool notify_ = false;
  int sock_ = -1;
  int wake_ = -1;
  long tid_ = 0;
  std::thread::id thread_;
  dev_t socket_dev_ = 0;
  ino_t socket_ino_ = 0;
  unsigned char* ring_ = nullptr;
  std::size_t ring_size_ = 0;
  std::uint64_t slots_ = 0, written_ = 0;
  std::deque<Trigger> queued_;
  std::optional<Trigger> current_;
  std::int64_t start_ns_ = 0, cpu_start_ns_ = 0;
  std::int64_t period_ns_ = 0, next_tick_ns_ = 0;
  std::uint64_t ticks_ = 0;
  bool registered_ = false;
  bool ended_ = false;
  std::string lost_;
  std::atomic<bool> interrupted_{false};

  std::string absent(const std::string& reason) const {
    return "no catanc enforcer at " + socket_path_ + " (" + reason + "): is `catanc run` running?";
  }

  void check_thread(const char* what) const {
    if (std::this_thread::get_id() != thread_) {
      throw Error("node '" + name_ + "' is registered by thread " + std::to_string(tid_) + ": call " + what +
                  "() from that thread (it is the thread the enforcer schedules)");
    }
  }

  void register_with_enforcer() {
    sock_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (sock_ < 0) throw Error(absent(std::string("socket: ") + std::strerror(errno)));
    sockaddr_un self{};
    self.sun_family = AF_UNIX;
    // Linux autobind: a unique abstract address that the enforcer and the previous node send to.
    if (::bind(sock_, reinterpret_cast<sockaddr*>(&self), sizeof(sa_family_t)) != 0) {
      throw Error(absent(std::string("bind: ") + std::strerror(errno)));
    }
    struct stat info {};
    if (::stat(socket_path_.c_str(), &info) != 0) throw Error(absent(std::strerror(errno)));
    socket_dev_ = info.st_dev;
    socket_ino_ = info.st_ino;
    const std::string hello = std::string(kProtocol) + " hello " + name_ + " " + std::to_string(::getpid()) + " " +
                              std::to_string(tid_) + (on_input_ ? " input" : "");
    sockaddr_un to{};
    const socklen_t length = detail::make_address(socket_path_, to);
    if (length == 0) throw Error(absent("the path is too long for a socket"));
    if (::sendto(sock_, hello.data(), hello.size(), 0, reinterpret_cast<sockaddr*>(&to), length) < 0) {
      throw Error(absent(std::strerror(errno)));
    }
    const std::int64_t deadline =
        detail::now_ns(CLOCK_MONOTONIC) + static_cast<std::int64_t>(kRegisterTimeoutS * 1e9);
    while (!stopped() && !registered_) {
      if (!receive(deadline)) {
        if (!lost_.empty()) throw Error(lost_);
        if (stopped()) break;  // interrupted while registering
        throw Error(absent("no answer in 5 s"));
      }
    }
  }

  void release() noexcept {
    if (sock_ >= 0) {
      if (!ended_ && period_ns_ == 0) {
        // Registered or not (interrupted before the welcome was read, the enforcer may have
        // registered it).  If the enforcer is gone or busy, it notices the thread is gone anyway.
        const std::string bye = std::string(kProtocol) + " bye " + name_ + " " + std::to_string(tid_);
        send_to(socket_path_, bye);
      }
      ::close(sock_);
      sock_ = -1;
    }
    if (ring_ != nullptr) {
      ::munmap(ring_, ring_size_);
      ring_ = nullptr;
    }
    if (wake_ >= 0) {
      ::close(wake_);
      wake_ = -1;
    }
  }

  bool send_to(const std::string& address, const std::string& datagram) noexcept {
    sockaddr_un to{};
    const socklen_t length = detail::make_address(address, to);
    if (length == 0 || sock_ < 0) return false;
    return ::sendto(sock_, datagram.data(), datagram.size(), MSG_DONTWAIT, reinterpret_cast<sockaddr*>(&to),
                    length) >= 0;
  }

  void start(Trigger trigger) {
    current_ = std::move(trigger);
    start_ns_ = detail::now_ns(CLOCK_MONOTONIC);
    cpu_start_ns_ = detail::now_ns(CLOCK_THREAD_CPUTIME_ID);
  }

  std::optional<Trigger> wait_until(std::int64_t deadline) {
    check_thread("wait");
    if (current_) finish(std::nullopt);
    if (period_ns_ > 0) return tick(deadline);
    if (standalone_) return std::nullopt;  // nothing triggers a node on its input
    while (!stopped()) {
      if (!queued_.empty()) {
        Trigger trigger = std::move(queued_.front());
        queued_.pop_front();
        start(trigger);
        return trigger;
      }
      if (!receive(deadline)) return std::nullopt;
    }
    return std::nullopt;
  }

  // The fallback timer: a trigger every period after registering; a late run skips the ticks it
  // overran, as a timer does, keeping the phase.
  std::optional<Trigger> tick(std::int64_t deadline) {
    std::int64_t now = detail::now_ns(CLOCK_MONOTONIC);
    if (now - next_tick_ns_ > period_ns_) next_tick_ns_ += (now - next_tick_ns_) / period_ns_ * period_ns_;
    while (!interrupted_.load()) {
      now = detail::now_ns(CLOCK_MONOTONIC);
      if (now >= next_tick_ns_) {
        next_tick_ns_ += period_ns_;
        Trigger trigger{name_, ++ticks_, 1};
        start(trigger);
        return trigger;
      }
      std::int64_t wait_ns = next_tick_ns_ - now;
      if (deadline >= 0) {
        if (now >= deadline) return std::nullopt;
        wait_ns = std::min(wait_ns, deadline - now);
      }
      pollfd ready{wake_, POLLIN, 0};
      const timespec timeout{static_cast<time_t>(wait_ns / 1000000000), static_cast<long>(wait_ns % 1000000000)};
      if (::ppoll(&ready, 1, &timeout, nullptr) > 0) drain_wake();
    }
    return std::nullopt;
  }

  void drain_wake() noexcept {
    std::uint64_t count = 0;
    while (::read(wake_, &count, sizeof count) > 0) {
    }
  }

  void finish(std::optional<double> compute_ms, Origin origin = Origin{0}) {
    check_thread("done");
    if (!current_) {
      throw Error("node '" + name_ + "': done() without a trigger (call it once per run, after wait())");
    }
    const Trigger trigger = std::move(*current_);
    current_.reset();
    const std::int64_t end_ns = detail::now_ns(CLOCK_MONOTONIC);
    std::uint64_t compute_ns = kUnknownCompute;
    if (!compute_ms) {
      const std::int64_t used = detail::now_ns(CLOCK_THREAD_CPUTIME_ID) - cpu_start_ns_;
      compute_ns = static_cast<std::uint64_t>(used > 0 ? used : 0);
    } else if (std::isfinite(*compute_ms) && *compute_ms >= 0.0 && *compute_ms < 1.8e13) {
      compute_ns = static_cast<std::uint64_t>(*compute_ms * 1e6);
    }
    if (period_ns_ > 0 || standalone_) return;  // on the timer, or no enforcer: nobody to tell
    drain();  // a route that changed while the run went on, a stop
    bool woke_next = false;
    if (!ended_ && !next_address_.empty() && trigger.seq != 0) {
      // The next node is gone if this fails: the enforcer sees its run lost.
      woke_next = send_to(next_address_, std::string(kProtocol) + " trigger " + next_node_ + " " +
                                             std::to_string(trigger.seq) + " " + std::to_string(next_threads_));
    }
    record(trigger, end_ns, compute_ns, detail::monotonic_origin(origin));  // after a stop too: the enforcer reads its last runs' reports
    if (!ended_ && notify_) {
      send_to(socket_path_, std::string(kProtocol) + " done " + name_ + " " + std::to_string(tid_) + " " +
                                std::to_string(trigger.seq));
    }
    // The next node shares this thread's priority (its subchain's), so on this CPU it would wait until
    // this thread blocks in its next wait(): let it run first, this thread's way back after.
    if (woke_next) ::sched_yield();
  }

  void record(const Trigger& trigger, std::int64_t end_ns, std::uint64_t compute_ns, std::uint64_t origin_ns) {
    if (ring_ == nullptr) return;
    // u64 seq, start_ns, end_ns, compute_ns; u32 threads, zero; u64 origin_ns (host byte order).
    const std::uint64_t times[4] = {trigger.seq, static_cast<std::uint64_t>(start_ns_),
                                    static_cast<std::uint64_t>(end_ns), compute_ns};
    const std::uint32_t threads[2] = {trigger.threads, 0};
    unsigned char* slot = ring_ + kRingHeaderSize + (written_ % slots_) * kRingEntrySize;
    std::memcpy(slot, times, sizeof times);
    std::memcpy(slot + 32, threads, sizeof threads);
    std::memcpy(slot + 40, &origin_ns, sizeof origin_ns);
    ++written_;
    // A release store: the entry is visible before the count that covers it.
    auto* written = reinterpret_cast<std::uint64_t*>(ring_ + kRingWrittenOffset);
#if defined(__GNUC__)
    __atomic_store_n(written, written_, __ATOMIC_RELEASE);
#else
    std::atomic_thread_fence(std::memory_order_release);
    *reinterpret_cast<volatile std::uint64_t*>(written) = written_;
#endif
  }

  // Takes every datagram waiting now (routes, stop; triggers are queued for wait()).
  void drain() {
    while (sock_ >= 0 && !ended_) {
      if (!receive_one(MSG_DONTWAIT)) return;
    }
  }

  // Reads one datagram; false when none was there (or the socket failed: the enforcer is lost).
  bool receive_one(int flags) {
    char data[kMaxDatagram + 1];
    sockaddr_un from{};
    alignas(cmsghdr) char control[CMSG_SPACE(sizeof(int))];
    iovec io{data, sizeof data};
    msghdr message{};
    message.msg_name = &from;
    message.msg_namelen = sizeof from;
    message.msg_iov = &io;
    message.msg_iovlen = 1;
    message.msg_control = control;
    message.msg_controllen = sizeof control;
    const ssize_t size = ::recvmsg(sock_, &message, flags | MSG_CMSG_CLOEXEC);
    if (size < 0) {
      if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) lose(std::strerror(errno));
      return false;
    }
    int fd = -1;
    for (cmsghdr* c = CMSG_FIRSTHDR(&message); c != nullptr; c = CMSG_NXTHDR(&message, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_RIGHTS) {
        const std::size_t count = (c->cmsg_len - CMSG_LEN(0)) / sizeof(int);
        for (std::size_t i = 0; i < count; ++i) {
          int passed = -1;
          std::memcpy(&passed, CMSG_DATA(c) + i * sizeof(int), sizeof passed);
          if (fd < 0 && count == 1) {
            fd = passed;
          } else {
            ::close(passed);
          }
        }
      }
    }
    const bool whole = (message.msg_flags & (MSG_TRUNC | MSG_CTRUNC)) == 0 && size <= static_cast<ssize_t>(kMaxDatagram);
    handle(whole ? detail::words(data, static_cast<std::size_t>(size)) : std::vector<std::string>{}, fd,
           detail::sender_address(from, message.msg_namelen));
    return true;
  }

  void handle(const std::vector<std::string>& w, int fd, const std::string& sender) {
    if (w.size() < 2 || w[0] != kProtocol) {
      if (fd >= 0) ::close(fd);
      return;  // not for this version (or a torn datagram): ignored
    }
    const std::string& kind = w[1];
    if (kind == "welcome" && !registered_) {
      welcome(w, fd, sender);
      return;
    }
    if (fd >= 0) ::close(fd);
    const bool from_enforcer = registered_ && sender == enforcer_;
    if (kind == "reject" && w.size() >= 3 && w[2] == name_) {
      if (from_enforcer || !registered_) {
        ended_ = true;
        std::string reason;
        for (std::size_t i = 3; i < w.size(); ++i) reason += (i > 3 ? " " : "") + w[i];
        throw Error("the catanc enforcer at " + socket_path_ + (registered_ ? " dropped" : " rejected") + " node '" +
                    name_ + "': " + reason);
      }
    } else if (kind == "trigger" && w.size() == 5 && w[2] == name_ &&
               (from_enforcer || (!prev_address_.empty() && sender == prev_address_))) {
      const auto seq = detail::number(w[3]);
      const auto threads = detail::number(w[4]);
      if (seq && threads) {
        if (queued_.size() >= 64) queued_.pop_front();  // bounded: a node that never waits
        queued_.push_back(Trigger{name_, *seq,
                                  static_cast<unsigned>(*threads < 1 ? 1 : *threads > 4096 ? 4096 : *threads)});
      }
    } else if (kind == "route" && w.size() == 8 && from_enforcer && w[2] == name_) {
      std::string next, prev;
      const auto threads = detail::number(w[5]);
      if (!threads || (w[3] != "0" && w[3] != "1") || !detail::parse_address(w[6], next) ||
          !detail::parse_address(w[7], prev)) {
        return;
      }
      notify_ = w[3] == "1";
      next_address_ = next;
      next_node_ = next.empty() ? std::string() : w[4];
      next_threads_ = static_cast<unsigned>(*threads < 1 ? 1 : *threads > 4096 ? 4096 : *threads);
      prev_address_ = prev;
    } else if (kind == "stop" && from_enforcer) {
      ended_ = true;
    }
  }

  void welcome(const std::vector<std::string>& w, int fd, const std::string& sender) {
    if (w.size() != 4 || w[2] != name_ || fd < 0) {
      if (fd >= 0) ::close(fd);
      return;
    }
    unsigned char header[24];
    struct stat info {};
    const bool read_ok = ::pread(fd, header, sizeof header, 0) == static_cast<ssize_t>(sizeof header) &&
                         ::fstat(fd, &info) == 0;
    std::uint32_t magic = 0, version = 0, slots = 0, entry_size = 0;
    std::uint64_t written = 0;
    std::memcpy(&magic, header, 4);
    std::memcpy(&version, header + 4, 4);
    std::memcpy(&slots, header + 8, 4);
    std::memcpy(&entry_size, header + 12, 4);
    std::memcpy(&written, header + 16, 8);
    const std::size_t size = kRingHeaderSize + static_cast<std::size_t>(slots) * kRingEntrySize;
    if (!read_ok || magic != kRingMagic || version != kRingVersion || entry_size != kRingEntrySize || slots == 0 ||
        static_cast<std::size_t>(info.st_size) < size) {
      ::close(fd);
      throw Error("node '" + name_ + "': the enforcer's ring is of another layout (version " +
                  std::to_string(version) + ")");
    }
    void* mapped = ::mmap(nullptr, size, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    ::close(fd);
    if (mapped == MAP_FAILED) throw Error("node '" + name_ + "': cannot map its ring: " + std::strerror(errno));
    ring_ = static_cast<unsigned char*>(mapped);
    ring_size_ = size;
    slots_ = slots;
    written_ = written;
    enforcer_ = sender;
    registered_ = true;
  }

  // Waits for and handles datagrams until something changed (a trigger queued, registered,
  // ended); false at the deadline, on interrupt, or once the enforcer is lost.
  bool receive(std::int64_t deadline) {
    while (true) {
      if (interrupted_.load() || ended_) return false;
      std::int64_t wait_ms = kProbeMs;
      if (deadline >= 0) {
        const std::int64_t left = deadline - detail::now_ns(CLOCK_MONOTONIC);
        wait_ms = std::min<std::int64_t>(wait_ms, left <= 0 ? 0 : (left + 999999) / 1000000);
      }
      pollfd ready[2] = {{sock_, POLLIN, 0}, {wake_, POLLIN, 0}};
      const int count = ::poll(ready, 2, static_cast<int>(wait_ms));
      if (count < 0 && errno != EINTR) {
        lose(std::strerror(errno));
        return false;
      }
      if (count > 0 && (ready[1].revents & POLLIN)) {
        drain_wake();
        continue;
      }
      if (count > 0 && ready[0].revents != 0) {
        const std::size_t before = queued_.size();
        const bool was_registered = registered_, was_ended = ended_;
        if (!receive_one(MSG_DONTWAIT)) {
          if (ended_) return false;  // lost
          continue;
        }
        if (queued_.size() != before || registered_ != was_registered || ended_ != was_ended) return true;
        continue;
      }
      if (deadline >= 0 && detail::now_ns(CLOCK_MONOTONIC) >= deadline) return false;
      if (count == 0 && !enforcer_alive()) {
        lose("it went away without stopping node '" + name_ + "'");
        return false;
      }
    }
  }

  // The enforcer is gone: end the loop (wait() returns empty), and say so once.
  void lose(const std::string& reason) {
    ended_ = true;
    lost_ = "lost the catanc enforcer at " + socket_path_ + ": " + reason;
    std::fprintf(stderr, "catanc: %s\n", lost_.c_str());
  }

  bool enforcer_alive() const {
    struct stat info {};
    if (::stat(socket_path_.c_str(), &info) != 0) return false;
    if (info.st_dev != socket_dev_ || info.st_ino != socket_ino_) return false;  // a new enforcer: not ours
    const int probe = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (probe < 0) return true;  // cannot tell: assume it is there
    sockaddr_un to{};
    const socklen_t length = detail::make_address(socket_path_, to);
    const int connected = ::connect(probe, reinterpret_cast<sockaddr*>(&to), length);
    const int error = errno;
    ::close(probe);
    return connected == 0 || (error != ECONNREFUSED && error != ENOENT);
  }
};

}  // namespace catanc

#endif  // CATANC_CLIENT_HPP
