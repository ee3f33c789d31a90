#include "process.hpp"

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>

extern char** environ;

namespace svo::tools {
namespace {

std::vector<std::string> environmentFor(const ProcessOptions& options) {
  std::vector<std::string> env;
  if (options.cLocale) env.emplace_back("LC_ALL=C");
  for (char** e = environ; *e; ++e)
    if (!options.cLocale || (std::strncmp(*e, "LC_", 3) != 0 && std::strncmp(*e, "LANG", 4) != 0))
      env.emplace_back(*e);
  return env;
}

}  // namespace

std::optional<ProcessResult> runProcess(const std::vector<std::string>& argv, const ProcessOptions& options) {
  int pipeFds[2];
  if (argv.empty() || ::pipe(pipeFds) != 0) return std::nullopt;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, pipeFds[1], 1);
  posix_spawn_file_actions_adddup2(&actions, pipeFds[1], 2);
  posix_spawn_file_actions_addclose(&actions, pipeFds[0]);
  if (!options.workingDirectory.empty())
    posix_spawn_file_actions_addchdir_np(&actions, options.workingDirectory.c_str());
  std::vector<std::string> arguments = argv, env = environmentFor(options);
  std::vector<char*> argp, envp;
  for (std::string& a : arguments) argp.push_back(a.data());
  argp.push_back(nullptr);
  for (std::string& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  pid_t pid = 0;
  const int spawned = ::posix_spawnp(&pid, argp[0], &actions, nullptr, argp.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  ::close(pipeFds[1]);
  ProcessResult result;
  char buffer[4096];
  for (ssize_t n; spawned == 0 && (n = ::read(pipeFds[0], buffer, sizeof buffer)) > 0;)
    result.output.append(buffer, std::size_t(n));
  ::close(pipeFds[0]);
  int status = 0;
  if (spawned != 0 || ::waitpid(pid, &status, 0) != pid) return std::nullopt;
  result.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

}  // namespace svo::tools
