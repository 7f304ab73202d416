/*
 * A QEMU TCG plugin (plugin API version 1, QEMU 7.x) that counts how often each guest
 * instruction below 4 MiB (the mps2-an386's code memory) executes, and writes one line
 * "ADDRESS COUNT" (hexadecimal address, decimal count) per executed instruction when QEMU
 * exits. tools/mcu_profile.sh builds it and attributes the counts to source lines.
 *
 *   qemu-system-arm ... -plugin ./libinsn_counts.so,arg=out=counts.txt
 *
 * Only the declarations it uses are written here, so that no QEMU source or development
 * package is needed; they are the API's own (include/qemu/qemu-plugin.h).
 */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef uint64_t qemu_plugin_id_t;
typedef struct {
    const char *target_name;
    struct {
        int min;
        int cur;
    } version;
    bool system_emulation;
    union {
        struct {
            int smp_vcpus;
            int max_vcpus;
        } system;
    };
} qemu_info_t;
struct qemu_plugin_tb;
struct qemu_plugin_insn;
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 };
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t, struct qemu_plugin_tb *);
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t, void *);
void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t, qemu_plugin_vcpu_tb_trans_cb_t);
void qemu_plugin_register_vcpu_insn_exec_inline(struct qemu_plugin_insn *, enum qemu_plugin_op,
                                                void *, uint64_t);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *, size_t);
uint64_t qemu_plugin_insn_vaddr(const struct qemu_plugin_insn *);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t, qemu_plugin_udata_cb_t, void *);

__attribute__((visibility("default"))) int qemu_plugin_version = 1;

/* One counter per halfword of the first 4 MiB: Thumb instructions are halfword-aligned. */
#define SLOTS (1u << 21)
static uint64_t counts[SLOTS];
static const char *out_path = "insn_counts.txt";
static bool written;

static void translated(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t address = qemu_plugin_insn_vaddr(insn);
        if (address < 2ull * SLOTS) {
            qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64,
                                                       &counts[address >> 1], 1);
        }
    }
}

/* Semihosting's exit ends QEMU with exit(), so the counts are written from atexit too. */
static void write_counts(void) {
    if (written) {
        return;
    }
    written = true;
    FILE *file = fopen(out_path, "w");
    if (file == NULL) {
        perror(out_path);
        return;
    }
    for (uint32_t slot = 0; slot < SLOTS; slot++) {
        if (counts[slot] != 0) {
            fprintf(file, "%x %llu\n", slot << 1, (unsigned long long)counts[slot]);
        }
    }
    fclose(file);
}

static void at_exit(qemu_plugin_id_t id, void *data) {
    (void)id;
    (void)data;
    write_counts();
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id,
                                                               const qemu_info_t *info,
                                                               int argc, char **argv) {
    (void)info;
    for (int i = 0; i < argc; i++) {
        if (strncmp(argv[i], "out=", 4) == 0) {
            out_path = argv[i] + 4;
        }
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, translated);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    atexit(write_counts);
    return 0;
}
