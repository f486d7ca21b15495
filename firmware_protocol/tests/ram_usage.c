/* Prints the static RAM the library needs per instance: built with the profile's -D flags. */
#include <stdio.h>

#include "hbp.h"

int main(void)
{
    printf("hbp_rx_t %u\n", (unsigned)sizeof(hbp_rx_t));
    printf("hbp_params_t %u\n", (unsigned)sizeof(hbp_params_t));
    printf("HBP_RX_MAX %u\n", (unsigned)HBP_RX_MAX);
    return 0;
}
