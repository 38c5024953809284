/*
 * A Modbus RTU master from libmodbus (Debian libmodbus-dev), for tests/monitor_peers.rs:
 * it polls a drive on an emulated line (`conformance bus`) while `conformance monitor`
 * listens on another endpoint. Built by the test with
 *
 *     cc client.c $(pkg-config --cflags --libs libmodbus)
 *
 *     client PORT ADDRESS POLLS     (9600 8E1)
 *
 * It reads 252FH (one register) POLLS times, 50 ms apart, then writes 04D2H to 2502H and
 * reads 2502H back. One line per operation on stdout: "read 252F 0510", "write 2502 ok",
 * "read 2502 04D2", or "read 252F error: MESSAGE" (a timeout, a CRC error: libmodbus's
 * own words). It does not retry (libmodbus has no retries of its own); its response
 * timeout is 500 ms. Exit status 0 when every operation got its answer, 1 otherwise,
 * 2 on bad arguments or a port that cannot be opened.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <modbus.h>

static int read_one(modbus_t *ctx, int reg)
{
    uint16_t v = 0;
    if (modbus_read_registers(ctx, reg, 1, &v) != 1) {
        printf("read %04X error: %s\n", reg, modbus_strerror(errno));
        return 1;
    }
    printf("read %04X %04X\n", reg, v);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: %s PORT ADDRESS POLLS\n", argv[0]);
        return 2;
    }
    int address = atoi(argv[2]);
    int polls = atoi(argv[3]);
    if (address < 1 || address > 247 || polls < 0 || polls > 10000) {
        fprintf(stderr, "bad ADDRESS or POLLS\n");
        return 2;
    }
    modbus_t *ctx = modbus_new_rtu(argv[1], 9600, 'E', 8, 1);
    if (ctx == NULL || modbus_set_slave(ctx, address) == -1) {
        fprintf(stderr, "modbus_new_rtu: %s\n", modbus_strerror(errno));
        return 2;
    }
    modbus_set_response_timeout(ctx, 0, 500000);
    if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "cannot open %s: %s\n", argv[1], modbus_strerror(errno));
        modbus_free(ctx);
        return 2;
    }
    int failed = 0;
    for (int i = 0; i < polls; i++) {
        failed |= read_one(ctx, 0x252F);
        usleep(50000);
    }
    if (modbus_write_register(ctx, 0x2502, 0x04D2) != 1) {
        printf("write 2502 error: %s\n", modbus_strerror(errno));
        failed = 1;
    } else {
        printf("write 2502 ok\n");
    }
    failed |= read_one(ctx, 0x2502);
    fflush(stdout);
    modbus_close(ctx);
    modbus_free(ctx);
    return failed;
}
