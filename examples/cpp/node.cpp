// A catanc node process in C++: one thread per node, each burning its compute time per trigger.
//
//     g++ -std=c++17 -O2 $(catanc client --cflags) -pthread examples/cpp/node.cpp -o node
//     CATANC_SOCKET=... ./node LM:12 LP:8          # under `catanc run` (it sets CATANC_SOCKET)
//     ./node LM:12 --fallback-ms 50                # without it: LM on its own 50 ms timer
//
// Each NAME:MS is a node whose thread burns MS ms of CPU per run.  SIGINT and SIGTERM end every
// loop (Node::interrupt() from the signal handler).  At the end it prints one line per run,
// "NAME SEQ START_NS END_NS" (CLOCK_MONOTONIC), and exits 0; 1 if a node failed or lost its
// enforcer (stderr says why), 2 for bad arguments.

#include <catanc/client.hpp>

#include <atomic>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <pthread.h>
#include <signal.h>

namespace {

constexpr std::size_t kMaxNodes = 16;
std::atomic<catanc::Node*> g_nodes[kMaxNodes];
std::atomic<bool> g_stop{false};

extern "C" void on_signal(int) {
  g_stop.store(true);
  for (auto& node : g_nodes) {
    if (catanc::Node* found = node.load()) found->interrupt();  // async-signal-safe
  }
}

double thread_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e3 + static_cast<double>(ts.tv_nsec) / 1e6;
}

void burn(double compute_ms) {
  const double start = thread_cpu_ms();
  while (thread_cpu_ms() - start < compute_ms) {
  }
}

struct Run {
  std::uint64_t seq;
  std::int64_t start_ns, end_ns;
};

struct Served {
  std::string name;
  double compute_ms = 0;
  std::vector<Run> runs;
  std::string error;  // catanc::Error's message, or why the enforcer was lost
};

std::mutex g_mutex;
std::condition_variable g_changed;
std::size_t g_ended = 0;
bool g_release = false;

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000 + ts.tv_nsec;
}

void serve(std::size_t index, Served& served, double fallback_ms) {
  try {
    catanc::Node node(served.name, fallback_ms);
    g_nodes[index].store(&node);
    if (g_stop.load()) node.interrupt();  // the signal came before the node was published
    while (auto trigger = node.wait()) {
      const std::int64_t start = monotonic_ns();
      burn(served.compute_ms);
      node.done();
      served.runs.push_back(Run{trigger->seq, start, monotonic_ns()});
    }
    served.error = node.lost();
    // Keep the node alive until main says so: the signal handler may still reach it until then.
    std::unique_lock<std::mutex> lock(g_mutex);
    ++g_ended;
    g_changed.notify_all();
    g_changed.wait(lock, [] { return g_release; });
    g_nodes[index].store(nullptr);
    return;
  } catch (const catanc::Error& error) {
    served.error = error.what();
  }
  std::lock_guard<std::mutex> lock(g_mutex);
  ++g_ended;
  g_changed.notify_all();
}

int usage(const char* why) {
  std::fprintf(stderr, "usage: node NAME:MS [NAME:MS ...] [--fallback-ms PERIOD]\nnode: %s\n", why);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<Served> nodes;
  double fallback_ms = 0.0;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--fallback-ms" && i + 1 < argc) {
      char* end = nullptr;
      fallback_ms = std::strtod(argv[++i], &end);
      if (*end != '\0' || !(fallback_ms > 0)) return usage("--fallback-ms takes a period in ms > 0");
      continue;
    }
    const auto colon = arg.find(':');
    char* end = nullptr;
    const double compute_ms = colon == std::string::npos ? -1.0 : std::strtod(arg.c_str() + colon + 1, &end);
    if (colon == std::string::npos || *end != '\0' || !(compute_ms >= 0)) {
      return usage(("expected NAME:MS, got '" + arg + "'").c_str());
    }
    nodes.push_back(Served{arg.substr(0, colon), compute_ms, {}, {}});
  }
  if (nodes.empty() || nodes.size() > kMaxNodes) return usage("give 1 to 16 nodes");

  // The handler runs in this thread only: the node threads start with the signals blocked.
  sigset_t handled;
  sigemptyset(&handled);
  sigaddset(&handled, SIGINT);
  sigaddset(&handled, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &handled, nullptr);
  std::vector<std::thread> threads;
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    threads.emplace_back(serve, i, std::ref(nodes[i]), fallback_ms);
  }
  struct sigaction action {};
  action.sa_handler = on_signal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  pthread_sigmask(SIG_UNBLOCK, &handled, nullptr);
  {
    std::unique_lock<std::mutex> lock(g_mutex);
    g_changed.wait(lock, [] { return g_ended > 0; });
    on_signal(0);  // a node that ended on its own (stopped, lost, failed) ends the others
    g_changed.wait(lock, [&] { return g_ended == nodes.size(); });
    g_release = true;
    g_changed.notify_all();
  }
  for (auto& thread : threads) thread.join();

  int status = 0;
  for (const auto& served : nodes) {
    for (const auto& run : served.runs) {
      std::printf("%s %llu %lld %lld\n", served.name.c_str(), static_cast<unsigned long long>(run.seq),
                  static_cast<long long>(run.start_ns), static_cast<long long>(run.end_ns));
    }
    if (!served.error.empty()) {
      std::fprintf(stderr, "node: %s: %s\n", served.name.c_str(), served.error.c_str());
      status = 1;
    }
  }
  return status;
}
