// The fault injector of the fault harness (issue #33), loaded with
// LD_PRELOAD into lightfarmd and lightfarm. It sees every call those
// processes make that changes a file, whoever makes it: our code through C++
// streams (libstdc++ opens with fopen and writes with write/writev),
// std::filesystem (mkdir, rename, link, copy_file_range/sendfile), OpenEXR
// (C++ streams), tinygltf (a string we write), and SQLite's unix VFS (open,
// pwrite64, ftruncate, fsync/fdatasync, close, which it takes from libc by
// symbol). glibc's own stdio writes (fwrite, fflush) call an internal write
// no shim can replace; nothing of ours writes a file through stdio, and the
// harness checks that: every file a dry run leaves behind must have been
// seen written here.
//
// The replaced calls have C linkage, and the shim calls no C++ library: it
// runs inside other processes' calls, on any of their threads.
//
// A "site" is the process's name, the operation, and the file's path below
// LF_FAULT_ROOT with its variable parts (ids, hashes, pids, pass numbers:
// any word with a digit in it, or 8 hex digits or more) written as '#', e.g.
// "lightfarmd write jobs/#/lightmap.pass-#.exr". The operations:
//   write     write, writev, pwrite(64), pwritev: the bytes
//   sync      fsync, fdatasync of a file or a directory: the bytes (or a
//             rename) reach the disk, or fail to
//   create    open(at)(64) for writing or creating, fopen(64) to write
//   mkdir     mkdir
//   rename    rename, renameat, renameat2 (the site is the new name)
//   link      link, linkat (the new name)
//   truncate  ftruncate(64)
//   copy      copy_file_range, sendfile (to the file)
//   close     close, fclose of a file opened for writing: the call closes
//             the file and then reports the error, as NFS does for a write
//             it could not make
//
//   LF_FAULT_ROOT   only files below this directory count
//   LF_FAULT_PROCS  the processes that count, by name (default "lightfarmd lightfarm")
//   LF_FAULT_LOG    every counted call appends "SITE\n" here (a dry run)
//   LF_FAULT_SITE   the site to fail
//   LF_FAULT_NTH    which of the site's calls after arming fails (default 1)
//   LF_FAULT_ERRNO  ENOSPC or EIO
//   LF_FAULT_ARMED  a file: while it holds only dots, each of the site's
//                   calls (in any process) appends one, and the NTH fails
//                   and appends an 'x'. The harness arms a fault where its
//                   scenario wants one by emptying the file, sees whether it
//                   was taken ('x'), and disarms it with a '-'.
#include <dlfcn.h>
#include <stdarg.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>

namespace {

int hexdigit(char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); }
int alnum(char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); }

// "jobs/4f2a…/lightmap.pass-0004.exr" -> "jobs/#/lightmap.pass-#.exr"
void normalise(const char* path, char* out, size_t size) {
    size_t o = 0;
    for (size_t i = 0; path[i] && o + 2 < size;) {
        if (!alnum(path[i])) {
            out[o++] = path[i++];
            continue;
        }
        size_t j = i, digits = 0, hex = 1;
        for (; alnum(path[j]); ++j) {
            digits += path[j] >= '0' && path[j] <= '9';
            hex &= hexdigit(path[j]);
        }
        if (digits > 0 || (hex && j - i >= 8)) {
            out[o++] = '#';
        } else {
            for (; i < j && o + 2 < size; ++i) out[o++] = path[i];
        }
        i = j;
    }
    out[o] = 0;
}

// The process's name as it started: PostgreSQL writes its processes'
// titles over argv[0], where program_invocation_short_name points, so the
// name is copied when the shim is loaded (children forked later keep it).
char process_name[64];

__attribute__((constructor)) void remember_process_name(void) {
    snprintf(process_name, sizeof process_name, "%s", program_invocation_short_name);
}

int counted_process(void) {
    const char* procs = getenv("LF_FAULT_PROCS");
    if (!procs) procs = "lightfarmd lightfarm";
    const size_t n = strlen(process_name);
    if (n == 0) return 0;
    for (const char* p = procs; (p = strstr(p, process_name)); p += n)
        if ((p == procs || p[-1] == ' ') && (p[n] == 0 || p[n] == ' ')) return 1;
    return 0;
}

// "PROC OP REL" for `path` (absolute) when it lies below the root and this
// process counts; 0 otherwise.
int site_of_absolute(const char* path, const char* op, char* site, size_t size) {
    const char* root = getenv("LF_FAULT_ROOT");
    if (!root || !counted_process()) return 0;
    const size_t root_len = strlen(root);
    if (strncmp(path, root, root_len) != 0 || path[root_len] != '/') return 0;
    char rel[4096];
    normalise(path + root_len + 1, rel, sizeof rel);
    snprintf(site, size, "%s %s %s", process_name, op, rel);
    return 1;
}

// The site of a call on the open file `fd`, or 0 when it is not one that
// counts (a pipe, a socket, a file outside the root, another process).
int site_of_fd(int fd, const char* op, char* site, size_t size) {
    struct stat st;
    if (!getenv("LF_FAULT_ROOT") || fstat(fd, &st) != 0 || !(S_ISREG(st.st_mode) || S_ISDIR(st.st_mode))) return 0;
    char link[64], path[4096];
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    const ssize_t n = readlink(link, path, sizeof path - 1);
    if (n <= 0) return 0;
    path[n] = 0;
    // An open file whose name was removed (SQLite's -shm at close) reads
    // "PATH (deleted)": its site is PATH's.
    const char* deleted = " (deleted)";
    if (size_t(n) > strlen(deleted) && strcmp(path + n - strlen(deleted), deleted) == 0) path[n - strlen(deleted)] = 0;
    return site_of_absolute(path, op, site, size);
}

// The site of a call on `path` relative to `dirfd` (AT_FDCWD: the working
// directory). The file itself may not exist yet: its directory is resolved
// when it exists, so that a path through a symbolic link still counts.
int site_of_path(int dirfd, const char* path, const char* op, char* site, size_t size) {
    if (!getenv("LF_FAULT_ROOT") || !path) return 0;
    char absolute[4096], base[4096];
    if (path[0] == '/') {
        snprintf(absolute, sizeof absolute, "%s", path);
    } else {
        if (dirfd == AT_FDCWD) {
            if (!getcwd(base, sizeof base)) return 0;
        } else {
            char link[64];
            snprintf(link, sizeof link, "/proc/self/fd/%d", dirfd);
            const ssize_t n = readlink(link, base, sizeof base - 1);
            if (n <= 0) return 0;
            base[n] = 0;
        }
        if (strlen(base) + 1 + strlen(path) >= sizeof absolute) return 0;
        strcpy(absolute, base);
        strcat(absolute, "/");
        strcat(absolute, path);
    }
    char* slash = strrchr(absolute, '/');
    char resolved[4096];
    if (slash && slash != absolute) {
        *slash = 0;
        const int found = realpath(absolute, resolved) != nullptr;
        *slash = '/';
        if (found && strlen(resolved) + strlen(slash) < sizeof resolved) {
            strcat(resolved, slash);
            return site_of_absolute(resolved, op, site, size);
        }
    }
    return site_of_absolute(absolute, op, site, size);
}

// libc's own calls, for the shim's files (the log, the armed file): never
// the replaced ones below.
#define NEXT(name) (reinterpret_cast<decltype(&name)>(dlsym(RTLD_NEXT, #name)))
ssize_t (*real_write)(int, const void*, size_t);

void append(const char* file, const char* text, size_t n) {
    if (!real_write) real_write = NEXT(write);
    const int fd = NEXT(open)(file, O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0) return;
    (void)!real_write(fd, text, n);
    NEXT(close)(fd);
}

// Whether the call at `site` fails: logs the site (a dry run), and counts
// it while the armed file holds only dots, failing the LF_FAULT_NTH. Sets
// errno to the fault's error when it fails.
int inject_at(char* site) {
    const char* log = getenv("LF_FAULT_LOG");
    const char* want = getenv("LF_FAULT_SITE");
    const char* armed = getenv("LF_FAULT_ARMED");
    if (log) {
        strcat(site, "\n");
        append(log, site, strlen(site));
        site[strlen(site) - 1] = 0;
    }
    if (!want || !armed || strcmp(site, want) != 0) return 0;
    char seen[256];
    const int fd = NEXT(open)(armed, O_RDONLY | O_CLOEXEC);
    if (fd < 0) return 0;
    const ssize_t n = read(fd, seen, sizeof seen);
    NEXT(close)(fd);
    if (n < 0 || size_t(n) >= sizeof seen || memchr(seen, 'x', size_t(n)) || memchr(seen, '-', size_t(n))) return 0;
    const char* nth_text = getenv("LF_FAULT_NTH");
    const long nth = nth_text ? atol(nth_text) : 1;
    if (n + 1 < nth) {
        append(armed, ".", 1);
        return 0;
    }
    append(armed, "x", 1);
    const char* code = getenv("LF_FAULT_ERRNO");
    errno = code && strcmp(code, "EIO") == 0 ? EIO : ENOSPC;
    return 1;
}

// Whether this call on `fd` fails; errno is kept for a call that goes on.
int inject(int fd, const char* op) {
    const int saved = errno;
    char site[4200];
    if (site_of_fd(fd, op, site, sizeof site) && inject_at(site)) return 1;
    errno = saved;
    return 0;
}

int inject_path(int dirfd, const char* path, const char* op) {
    const int saved = errno;
    char site[4200];
    if (site_of_path(dirfd, path, op, site, sizeof site) && inject_at(site)) return 1;
    errno = saved;
    return 0;
}

int opens_to_write(int flags) { return (flags & O_ACCMODE) != O_RDONLY || (flags & (O_CREAT | O_TRUNC)); }
int opens_to_write(const char* mode) { return mode && (strchr(mode, 'w') || strchr(mode, 'a') || strchr(mode, '+')); }

// The mode argument of open, present with O_CREAT or O_TMPFILE.
#define OPEN_MODE(flags)                     \
    mode_t mode = 0;                         \
    if ((flags) & (O_CREAT | __O_TMPFILE)) { \
        va_list args;                        \
        va_start(args, flags);               \
        mode = mode_t(va_arg(args, int));    \
        va_end(args);                        \
    }

}  // namespace

extern "C" {

ssize_t write(int fd, const void* buf, size_t n) {
    if (inject(fd, "write")) return -1;
    if (!real_write) real_write = NEXT(write);
    return real_write(fd, buf, n);
}

ssize_t writev(int fd, const struct iovec* iov, int count) {
    if (inject(fd, "write")) return -1;
    return NEXT(writev)(fd, iov, count);
}

ssize_t pwrite(int fd, const void* buf, size_t n, off_t at) {
    if (inject(fd, "write")) return -1;
    return NEXT(pwrite)(fd, buf, n, at);
}

ssize_t pwrite64(int fd, const void* buf, size_t n, off64_t at) {
    if (inject(fd, "write")) return -1;
    return NEXT(pwrite64)(fd, buf, n, at);
}

ssize_t pwritev(int fd, const struct iovec* iov, int count, off_t at) {
    if (inject(fd, "write")) return -1;
    return NEXT(pwritev)(fd, iov, count, at);
}

int fsync(int fd) {
    if (inject(fd, "sync")) return -1;
    return NEXT(fsync)(fd);
}

int fdatasync(int fd) {
    if (inject(fd, "sync")) return -1;
    return NEXT(fdatasync)(fd);
}

int open(const char* path, int flags, ...) {
    OPEN_MODE(flags)
    if (opens_to_write(flags) && inject_path(AT_FDCWD, path, "create")) return -1;
    return NEXT(open)(path, flags, mode);
}

int open64(const char* path, int flags, ...) {
    OPEN_MODE(flags)
    if (opens_to_write(flags) && inject_path(AT_FDCWD, path, "create")) return -1;
    return NEXT(open64)(path, flags, mode);
}

int openat(int dirfd, const char* path, int flags, ...) {
    OPEN_MODE(flags)
    if (opens_to_write(flags) && inject_path(dirfd, path, "create")) return -1;
    return NEXT(openat)(dirfd, path, flags, mode);
}

int openat64(int dirfd, const char* path, int flags, ...) {
    OPEN_MODE(flags)
    if (opens_to_write(flags) && inject_path(dirfd, path, "create")) return -1;
    return NEXT(openat64)(dirfd, path, flags, mode);
}

FILE* fopen(const char* path, const char* mode) {
    if (opens_to_write(mode) && inject_path(AT_FDCWD, path, "create")) return nullptr;
    return NEXT(fopen)(path, mode);
}

FILE* fopen64(const char* path, const char* mode) {
    if (opens_to_write(mode) && inject_path(AT_FDCWD, path, "create")) return nullptr;
    return NEXT(fopen64)(path, mode);
}

int mkdir(const char* path, mode_t mode) {
    if (inject_path(AT_FDCWD, path, "mkdir")) return -1;
    return NEXT(mkdir)(path, mode);
}

int rename(const char* from, const char* to) {
    if (inject_path(AT_FDCWD, to, "rename")) return -1;
    return NEXT(rename)(from, to);
}

int renameat(int from_dir, const char* from, int to_dir, const char* to) {
    if (inject_path(to_dir, to, "rename")) return -1;
    return NEXT(renameat)(from_dir, from, to_dir, to);
}

int renameat2(int from_dir, const char* from, int to_dir, const char* to, unsigned flags) {
    if (inject_path(to_dir, to, "rename")) return -1;
    return NEXT(renameat2)(from_dir, from, to_dir, to, flags);
}

int link(const char* from, const char* to) {
    if (inject_path(AT_FDCWD, to, "link")) return -1;
    return NEXT(link)(from, to);
}

int linkat(int from_dir, const char* from, int to_dir, const char* to, int flags) {
    if (inject_path(to_dir, to, "link")) return -1;
    return NEXT(linkat)(from_dir, from, to_dir, to, flags);
}

int ftruncate(int fd, off_t length) {
    if (inject(fd, "truncate")) return -1;
    return NEXT(ftruncate)(fd, length);
}

int ftruncate64(int fd, off64_t length) {
    if (inject(fd, "truncate")) return -1;
    return NEXT(ftruncate64)(fd, length);
}

ssize_t copy_file_range(int in, off64_t* in_at, int out, off64_t* out_at, size_t n, unsigned flags) {
    if (inject(out, "copy")) return -1;
    return NEXT(copy_file_range)(in, in_at, out, out_at, n, flags);
}

ssize_t sendfile(int out, int in, off_t* at, size_t n) {
    if (inject(out, "copy")) return -1;
    return NEXT(sendfile)(out, in, at, n);
}

ssize_t sendfile64(int out, int in, off64_t* at, size_t n) {
    if (inject(out, "copy")) return -1;
    return NEXT(sendfile64)(out, in, at, n);
}

// A close that fails has still closed the file (POSIX leaves it open to the
// system; Linux always closes): the error is reported after the real close.
int close(int fd) {
    const int writable = (fcntl(fd, F_GETFL) & O_ACCMODE) != O_RDONLY;
    const int fails = writable && inject(fd, "close");
    const int saved = errno;
    const int result = NEXT(close)(fd);
    if (!fails) return result;
    errno = saved;
    return -1;
}

int fclose(FILE* stream) {
    const int fd = stream ? fileno(stream) : -1;
    const int writable = fd >= 0 && (fcntl(fd, F_GETFL) & O_ACCMODE) != O_RDONLY;
    const int fails = writable && inject(fd, "close");
    const int saved = errno;
    const int result = NEXT(fclose)(stream);
    if (!fails) return result;
    errno = saved;
    return EOF;
}

}  // extern "C"
