/* Loaded with LD_PRELOAD by `mogo bench avx2` (mogo.bench.speed.avx2_only): the process sees a
 * CPU without AVX-512, AVX-VNNI and AMX, so onnxruntime's MLAS and numpy pick their AVX2
 * kernels, as on a CPU that has only AVX2.
 *
 * Linux's CPUID faulting (arch_prctl ARCH_SET_CPUID, 0) makes every CPUID instruction of the
 * process raise SIGSEGV; the handler runs the real CPUID, clears those feature bits and steps
 * over the instruction. Threads and forks inherit the faulting; an exec clears it, and the
 * LD_PRELOAD the child inherits sets it again. The program's own SIGSEGV action (Python's
 * faulthandler, Node's) is kept aside: sigaction() and signal() for SIGSEGV set and report it,
 * while this handler stays installed and passes it every other SIGSEGV, so a real fault ends
 * as it would have. C, not Python: a signal handler that edits the faulting thread's registers
 * must run on that thread at once, which Python's handlers cannot.
 */
#define _GNU_SOURCE
#include <asm/prctl.h>
#include <cpuid.h>
#include <dlfcn.h>
#include <signal.h>
#include <stdint.h>
#include <string.h>
#include <sys/syscall.h>
#include <ucontext.h>
#include <unistd.h>

#define BIT(n) (1u << (n))

static long cpuid_enabled(int on) { return syscall(SYS_arch_prctl, ARCH_SET_CPUID, on); }

typedef int (*sigaction_fn)(int, const struct sigaction *, struct sigaction *);
static sigaction_fn real_sigaction;
static struct sigaction theirs; /* the program's SIGSEGV action: SIG_DFL until it sets one */

static int install(int signal_number, const struct sigaction *action, struct sigaction *old) {
    if (!real_sigaction)
        real_sigaction = (sigaction_fn)dlsym(RTLD_NEXT, "sigaction");
    return real_sigaction(signal_number, action, old);
}

int sigaction(int signal_number, const struct sigaction *action, struct sigaction *old) {
    if (signal_number != SIGSEGV)
        return install(signal_number, action, old);
    if (old)
        *old = theirs;
    if (action)
        theirs = *action;
    return 0;
}

sighandler_t signal(int signal_number, sighandler_t handler) {
    if (signal_number != SIGSEGV) {
        sighandler_t (*real_signal)(int, sighandler_t) = dlsym(RTLD_NEXT, "signal");
        return real_signal(signal_number, handler);
    }
    sighandler_t previous = theirs.sa_handler;
    memset(&theirs, 0, sizeof theirs);
    theirs.sa_handler = handler;
    theirs.sa_flags = SA_RESTART;
    return previous;
}

/* A SIGSEGV that is not CPUID's, as the program asked: its handler, or the default action
 * (restored for the fault to happen again on return, and end the process). */
static void pass_on(int signal_number, siginfo_t *info, void *context) {
    struct sigaction action = theirs;
    if (action.sa_flags & SA_RESETHAND) {
        memset(&theirs, 0, sizeof theirs);
        theirs.sa_handler = SIG_DFL;
    }
    if (action.sa_flags & SA_SIGINFO)
        action.sa_sigaction(signal_number, info, context);
    else if (action.sa_handler != SIG_DFL && action.sa_handler != SIG_IGN)
        action.sa_handler(signal_number);
    else {
        struct sigaction fallback = {0};
        fallback.sa_handler = SIG_DFL;
        install(signal_number, &fallback, 0);
    }
}

/* leaf 7 subleaf 0: EBX AVX512 F DQ IFMA PF ER CD BW VL; ECX AVX512 VBMI VBMI2 VNNI BITALG
 * VPOPCNTDQ; EDX AVX512 4VNNIW 4FMAPS VP2INTERSECT, AMX-BF16, AVX512-FP16, AMX-TILE, AMX-INT8.
 * leaf 7 subleaf 1: EAX AVX-VNNI, AVX512-BF16, AMX-FP16, AVX-IFMA. */
static void hide(unsigned leaf, unsigned sub, unsigned *a, unsigned *b, unsigned *c,
                 unsigned *d) {
    if (leaf == 7 && sub == 0) {
        *b &= ~(BIT(16) | BIT(17) | BIT(21) | BIT(26) | BIT(27) | BIT(28) | BIT(30) | BIT(31));
        *c &= ~(BIT(1) | BIT(6) | BIT(11) | BIT(12) | BIT(14));
        *d &= ~(BIT(2) | BIT(3) | BIT(8) | BIT(22) | BIT(23) | BIT(24) | BIT(25));
    } else if (leaf == 7 && sub == 1) {
        *a &= ~(BIT(4) | BIT(5) | BIT(21) | BIT(23));
    }
}

static void on_segv(int signal_number, siginfo_t *info, void *context) {
    greg_t *r = ((ucontext_t *)context)->uc_mcontext.gregs;
    const uint8_t *at = (const uint8_t *)r[REG_RIP];
    /* a faulted CPUID comes as SI_KERNEL (a general protection fault) with RIP on it; a page
     * fault (RIP may not be readable) or a raised SIGSEGV is the program's */
    if (info->si_code != SI_KERNEL || at[0] != 0x0f || at[1] != 0xa2) {
        pass_on(signal_number, info, context);
        return;
    }
    unsigned leaf = (unsigned)r[REG_RAX], sub = (unsigned)r[REG_RCX], a, b, c, d;
    cpuid_enabled(1);
    __cpuid_count(leaf, sub, a, b, c, d);
    cpuid_enabled(0);
    hide(leaf, sub, &a, &b, &c, &d);
    r[REG_RAX] = a;
    r[REG_RBX] = b;
    r[REG_RCX] = c;
    r[REG_RDX] = d;
    r[REG_RIP] += 2;
}

__attribute__((constructor)) static void start(void) {
    struct sigaction action = {0};
    action.sa_sigaction = on_segv;
    action.sa_flags = SA_SIGINFO | SA_ONSTACK | SA_NODEFER; /* NODEFER: a fault inside theirs */
    theirs.sa_handler = SIG_DFL;
    install(SIGSEGV, &action, 0);
    cpuid_enabled(0);
}
