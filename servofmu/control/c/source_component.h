/* component.h of a signal source: stateless, its table is in source_table.h. */
typedef struct {
    int unused;
} ScState;
