/*
 * A generic Modbus RTU slave from libmodbus (Debian libmodbus-dev), on a serial port (a
 * pseudo-terminal in the tests): one node with 65536 holding registers (0000H..FFFFH),
 * all zero, and nothing TECO-specific. tests/libmodbus_device.rs builds it with
 *
 *     cc server.c $(pkg-config --cflags --libs libmodbus)
 *
 * and checks it as an F510, as tests/generic_device.rs does with pymodbus's server.
 *
 *     server PORT [ADDRESS [START COUNT]]
 *
 * 9600 8N1; ADDRESS 1..247, default 1; START and COUNT (default 0 and 65536) the holding
 * registers it serves, START..START+COUNT-1: a read outside gets exception 02H.
 *
 * stdout carries one line, "ready", once the port is open; diagnostics go to stderr.
 * Bad input never ends the server: a frame with a bad CRC, a frame cut short, a frame
 * for another node are dropped (the input flushed) and it listens again. SIGTERM or
 * SIGINT ends it within one indication timeout (100 ms), with exit status 0; a port that
 * fails (the pty's peer gone) ends it with status 1.
 */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <modbus.h>

static volatile sig_atomic_t stop;

static void on_signal(int sig)
{
    (void)sig;
    stop = 1;
}

int main(int argc, char **argv)
{
    if (argc != 2 && argc != 3 && argc != 5) {
        fprintf(stderr, "usage: %s PORT [ADDRESS [START COUNT]]\n", argv[0]);
        return 2;
    }
    long start = 0, count = 0x10000;
    if (argc == 5) {
        char *end1 = NULL, *end2 = NULL;
        start = strtol(argv[3], &end1, 0);
        count = strtol(argv[4], &end2, 0);
        if (*end1 != '\0' || *end2 != '\0' || start < 0 || count < 1 || start + count > 0x10000) {
            fprintf(stderr, "START %s COUNT %s: a block inside 0..65535\n", argv[3], argv[4]);
            return 2;
        }
    }
    int address = 1;
    if (argc >= 3) {
        char *end = NULL;
        long a = strtol(argv[2], &end, 0);
        if (*argv[2] == '\0' || *end != '\0' || a < 1 || a > 247) {
            fprintf(stderr, "address %s: give 1..247\n", argv[2]);
            return 2;
        }
        address = (int)a;
    }

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);

    modbus_t *ctx = modbus_new_rtu(argv[1], 9600, 'N', 8, 1);
    if (ctx == NULL) {
        fprintf(stderr, "modbus_new_rtu: %s\n", modbus_strerror(errno));
        return 2;
    }
    if (modbus_set_slave(ctx, address) == -1) {
        fprintf(stderr, "modbus_set_slave: %s\n", modbus_strerror(errno));
        modbus_free(ctx);
        return 2;
    }
    /* By default the whole register space, so that every F510 register (and every
     * other) reads. */
    modbus_mapping_t *map =
        modbus_mapping_new_start_address(0, 0, 0, 0, (unsigned int)start, (int)count, 0, 0);
    if (map == NULL) {
        fprintf(stderr, "modbus_mapping_new_start_address: %s\n", modbus_strerror(errno));
        modbus_free(ctx);
        return 2;
    }
    if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "modbus_connect %s: %s\n", argv[1], modbus_strerror(errno));
        modbus_mapping_free(map);
        modbus_free(ctx);
        return 2;
    }
    /* libmodbus restarts select() on EINTR, so a signal alone would not wake the loop:
     * modbus_receive returns every 100 ms without a frame to let it see the flag. */
    modbus_set_indication_timeout(ctx, 0, 100000);

    printf("ready\n");
    fflush(stdout);

    uint8_t req[MODBUS_RTU_MAX_ADU_LENGTH];
    int status = 0;
    while (!stop) {
        int rc = modbus_receive(ctx, req);
        if (rc > 0) {
            if (modbus_reply(ctx, req, rc, map) == -1) {
                fprintf(stderr, "modbus_reply: %s\n", modbus_strerror(errno));
            }
        } else if (rc == -1 && errno >= MODBUS_ENOBASE) {
            /* Bad input (a bad CRC, a bad byte count): drop what is pending, listen on. */
            fprintf(stderr, "modbus_receive: %s\n", modbus_strerror(errno));
            modbus_flush(ctx);
        } else if (rc == -1 && errno != ETIMEDOUT && errno != EINTR) {
            /* The port itself failed (the peer closed the pty: EIO, ECONNRESET). */
            fprintf(stderr, "modbus_receive: %s\n", modbus_strerror(errno));
            status = 1;
            break;
        }
        /* rc == 0: a frame for another node, filtered by libmodbus. */
    }

    modbus_close(ctx);
    modbus_mapping_free(map);
    modbus_free(ctx);
    return status;
}
