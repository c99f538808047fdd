/* Runs every test; the last line is "<n> passed, <m> failed"; the exit status says it too. */
#include "tinytest.h"

#include <stdlib.h>

int tt_current_failed;
static int passed, failed;

void tt_run(const char *name, tt_fn fn)
{
    tt_current_failed = 0;
    fn();
    if (tt_current_failed) {
        printf("FAILED %s\n", name);
        failed++;
    } else {
        passed++;
    }
}

int main(void)
{
#if defined(CFG_HEAD_SERVO)
    servo_tests();
#else
    protocol_tests();
    motion_tests();
    head_tests();
    head_id_tests();
#endif
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? EXIT_FAILURE : EXIT_SUCCESS;
}
